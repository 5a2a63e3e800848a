/* What the MLP upscaler's kernels share (mlp_upscale.cl, mlp_train.cl):
 * the geometry and transform constants, the packed weight layout and the gamma ramp of
 * the seed's transform. The values come as -D options from
 * clss/methods/mlp/transform.py (kernel_defines), the one place they are written; the
 * defaults below are the 2x setting, for a porter building a source as it is. */
#ifndef MLP_LAYOUT_H
#define MLP_LAYOUT_H

#ifndef S
#define S 2
#define B 4
#define FEATURE 1
#define GAMMA 2.0f
#define INV_GAMMA 0.5f
#define EPS 0.001f
#define EPS_ROOT 0.0316227766f
#define ALPHA 0.01f
#endif

/* 5x5 neighbourhoods of the beauty and the feature pass -> 50 -> 50 -> 25 */
#define TAPS 5
#define NT (TAPS * TAPS)
#define NI (2 * NT)
#define NH 50
#define NO 25
#define BB (B * B)
/* packed weights: [W1 (NH x NI), b1, W2 (NH x NH), b2, W3 (NO x NH), b3] */
#define OFF1 0
#define OFF2 (OFF1 + NH * NI + NH)
#define OFF3 (OFF2 + NH * NH + NH)

/* the gamma ramp of a DC-free residual, and its inverse (transform.ramp / ramp_inv) */
inline float mlp_ramp(float r)
{
    return sign(r) * (pow(fabs(r) + (float)EPS, (float)INV_GAMMA) - (float)EPS_ROOT);
}

inline float mlp_ramp_inv(float y)
{
    return sign(y) * (pow(fabs(y) + (float)EPS_ROOT, (float)GAMMA) - (float)EPS);
}

#endif
