/* mlp_train: online training of the shader MLP upscaler on the device (seed 004, Spencer
 * 2022: the network learns inside the renderer while it upscales; docs/methods/mlp.md).
 * One optimiser step on a batch of patches is four launches, fp32 throughout:
 *
 *   mlp_train_forward   per sample (patch, channel, render pixel): the frame step's
 *                       gather + DC removal + gamma ramp + MLP, keeping the layer
 *                       activations for the backward pass, and the block values;
 *   mlp_train_loss      per loss pixel: the overlap mean of the blocks covering it minus
 *                       the reference (the L1 loss's residual);
 *   mlp_train_backward  per sample: dL/dy of its block units (sign of the residual at
 *                       the unit's pixel / its block count / the loss's element count,
 *                       through the inverse ramp), then back through the two hidden
 *                       layers;
 *   mlp_train_wgrad     per parameter of one layer: the sum over samples of delta x input
 *                       (bias: of delta), in the packed layout of the inference weights;
 *   mlp_train_adam      per parameter: torch.optim.Adam's update (bias-corrected, eps
 *                       added after the square root), in place on the packed weights the
 *                       frame step reads.
 *
 * The batch is host-cut crops, PQ-encoded (clss/methods/mlp/online.py):
 *   col  [P][3][C][C]       colour crops, C = PATCH + 2*MARGIN render pixels;
 *   feat [P][S*C][S*C]      depth crops at output resolution (FEATURE=1);
 *   ref  [P][3][L][L]       the reference over the loss region, L = S*PATCH output pixels,
 *                           at output pixels S*MARGIN .. S*MARGIN+L-1 of the crop.
 * Samples are the render pixels whose blocks reach the loss region: R x R = (PATCH+2)^2
 * per patch and channel, crop pixels MARGIN-1 .. MARGIN+PATCH; sample n = ((p*3 + c)*R +
 * a)*R + b. Per-sample buffers are feature-major ([K][N]) so that the weight-gradient
 * sums walk contiguous memory. Geometry and constants: -D options from
 * clss/methods/mlp/transform.py (as mlp_upscale.cl), plus -DPATCH, -DMARGIN.
 */
#include "common.h"

#include "mlp_layout.h"

#ifndef PATCH
#define PATCH 16
#define MARGIN 3
#endif

#define C (PATCH + 2 * MARGIN)
#define R (PATCH + 2)
#define L (S * PATCH)
#define SC (S * C)

/* d ramp_inv / dy as autograd takes it: sign(y) * f(|y|) -> sign(y)^2 f'(|y|), so 0 at
 * y == 0 exactly (why a zero output layer cannot learn, and the init keeps it small and
 * random) */
inline float mt_ramp_inv_grad(float y)
{
    const float sg = sign(y);
    return sg * sg * (float)GAMMA * pow(fabs(y) + (float)EPS_ROOT, (float)GAMMA - 1.0f);
}

/** @param[in]  col, feat   the batch's crops (see the top of this file)
 *  @param[in]  wp          the packed weights (float, the inference layout)
 *  @param[out] X           [NI][N] the transformed inputs
 *  @param[out] H1, H2      [NH][N] the hidden activations (after the leaky ReLU)
 *  @param[out] Y           [BB][N] the output layer (the block's units in the ramp domain)
 *  @param[out] BLK         [BB][N] the block values (PQ): mean + ramp_inv(y)
 *  @param[in]  n_samples   N = P * 3 * R * R
 *  NDRange: N rounded up; the kernel guards. */
__kernel void mlp_train_forward(__global const float *col, __global const float *feat,
                                __global const float *wp, __global float *X,
                                __global float *H1, __global float *H2, __global float *Y,
                                __global float *BLK, int n_samples)
{
    const int n = get_global_id(0);
    if (n >= n_samples)
        return;
    const int b = n % R, a = (n / R) % R, pc = n / (R * R), p = pc / 3;
    const int i = a + MARGIN - 1, j = b + MARGIN - 1;     /* crop render pixel */
    float x[NI], h1[NH], h2[NH];

    __global const float *cc = col + (long)pc * C * C;
    float m = 0.0f;
    for (int dy = 0; dy < TAPS; ++dy)
        for (int dx = 0; dx < TAPS; ++dx) {
            const float v = cc[(i - 2 + dy) * C + (j - 2 + dx)];
            x[dy * TAPS + dx] = v;
            m += v;
        }
    m *= 1.0f / NT;
    for (int k = 0; k < NT; ++k)
        x[k] = mlp_ramp(x[k] - m);
#if FEATURE
    {
        __global const float *ff = feat + (long)p * SC * SC;
        float mf = 0.0f;
        for (int dy = 0; dy < TAPS; ++dy)
            for (int dx = 0; dx < TAPS; ++dx) {
                const float v = ff[(S * i - 1 + dy) * SC + (S * j - 1 + dx)];
                x[NT + dy * TAPS + dx] = v;
                mf += v;
            }
        mf *= 1.0f / NT;
        for (int k = 0; k < NT; ++k)
            x[NT + k] = mlp_ramp(x[NT + k] - mf);
    }
#else
    for (int k = 0; k < NT; ++k)
        x[NT + k] = 0.0f;
#endif
    for (int k = 0; k < NI; ++k)
        X[(long)k * n_samples + n] = x[k];

    for (int o = 0; o < NH; ++o) {
        float z = wp[OFF1 + NH * NI + o];
        for (int q = 0; q < NI; ++q)
            z = fma(wp[OFF1 + o * NI + q], x[q], z);
        h1[o] = z > 0.0f ? z : z * (float)ALPHA;
        H1[(long)o * n_samples + n] = h1[o];
    }
    for (int o = 0; o < NH; ++o) {
        float z = wp[OFF2 + NH * NH + o];
        for (int q = 0; q < NH; ++q)
            z = fma(wp[OFF2 + o * NH + q], h1[q], z);
        h2[o] = z > 0.0f ? z : z * (float)ALPHA;
        H2[(long)o * n_samples + n] = h2[o];
    }
    for (int o = 0; o < BB; ++o) {
        float y = wp[OFF3 + NO * NH + o];
        for (int q = 0; q < NH; ++q)
            y = fma(wp[OFF3 + o * NH + q], h2[q], y);
        Y[(long)o * n_samples + n] = y;
        BLK[(long)o * n_samples + n] = m + mlp_ramp_inv(y);
    }
}

/** @param[in]  BLK        [BB][N] from mlp_train_forward
 *  @param[in]  ref        [P][3][L][L] the reference (PQ) over the loss region
 *  @param[out] diff       [P][3][L][L] the folded output minus the reference
 *  NDRange: P*3*L*L rounded up; the kernel guards. Inside the loss region every covering
 *  block is a sample (MARGIN >= 1), and the counts are the whole frame's (the crop lies
 *  MARGIN render pixels inside it). */
__kernel void mlp_train_loss(__global const float *BLK, __global const float *ref,
                             __global float *diff, int n_samples)
{
    const int g = get_global_id(0);
    if (g >= n_samples / (R * R) * L * L)
        return;
    const int x = g % L + S * MARGIN, y = (g / L) % L + S * MARGIN, pc = g / (L * L);
    const int ihi = (y + 1) / S, jhi = (x + 1) / S;
    float acc = 0.0f;
    int cnt = 0;
    for (int i = ihi - 1; i <= ihi; ++i) {
        if (S * i < y - S)
            continue;
        for (int j = jhi - 1; j <= jhi; ++j) {
            if (S * j < x - S)
                continue;
            const int k = (y + 1 - S * i) * B + (x + 1 - S * j);
            const int n = (pc * R + (i - MARGIN + 1)) * R + (j - MARGIN + 1);
            acc += BLK[(long)k * n_samples + n];
            ++cnt;
        }
    }
    diff[g] = acc / (float)cnt - ref[g];
}

/* the number of blocks covering output pixel (y, x) of a crop (interior) */
inline int mt_cover(int y, int x)
{
    const int ihi = (y + 1) / S, jhi = (x + 1) / S;
    int cnt = 0;
    for (int i = ihi - 1; i <= ihi; ++i)
        for (int j = jhi - 1; j <= jhi; ++j)
            cnt += (S * i >= y - S) && (S * j >= x - S);
    return cnt;
}

/** @param[in]  wp          the packed weights
 *  @param[in]  H1, H2, Y   from mlp_train_forward
 *  @param[in]  diff        from mlp_train_loss
 *  @param[out] D1, D2      [NH][N] dL/dz of the hidden layers
 *  @param[out] D3          [BB][N] dL/dy of the output layer's block units
 *  @param[in]  inv_count   1 / (P * 3 * L * L): the L1 loss is a mean
 *  NDRange: N rounded up; the kernel guards. */
__kernel void mlp_train_backward(__global const float *wp, __global const float *H1,
                                 __global const float *H2, __global const float *Y,
                                 __global const float *diff, __global float *D1,
                                 __global float *D2, __global float *D3, int n_samples,
                                 float inv_count)
{
    const int n = get_global_id(0);
    if (n >= n_samples)
        return;
    const int b = n % R, a = (n / R) % R, pc = n / (R * R);
    const int i = a + MARGIN - 1, j = b + MARGIN - 1;
    float d3[BB], d2[NH];
    for (int k = 0; k < BB; ++k) {
        const int y = S * i - 1 + k / B - S * MARGIN, x = S * j - 1 + k % B - S * MARGIN;
        float g = 0.0f;
        if (y >= 0 && y < L && x >= 0 && x < L) {
            const float r = diff[((long)pc * L + y) * L + x];
            g = sign(r) * inv_count / (float)mt_cover(y + S * MARGIN, x + S * MARGIN);
        }
        d3[k] = g * mt_ramp_inv_grad(Y[(long)k * n_samples + n]);
        D3[(long)k * n_samples + n] = d3[k];
    }
    for (int q = 0; q < NH; ++q) {
        float s = 0.0f;
        for (int o = 0; o < BB; ++o)
            s = fma(wp[OFF3 + o * NH + q], d3[o], s);
        const float h = H2[(long)q * n_samples + n];
        d2[q] = h > 0.0f ? s : s * (float)ALPHA;
        D2[(long)q * n_samples + n] = d2[q];
    }
    for (int q = 0; q < NH; ++q) {
        float s = 0.0f;
        for (int o = 0; o < NH; ++o)
            s = fma(wp[OFF2 + o * NH + q], d2[o], s);
        const float h = H1[(long)q * n_samples + n];
        D1[(long)q * n_samples + n] = h > 0.0f ? s : s * (float)ALPHA;
    }
}

/** One layer's gradient: G[woff + o*ci + q] = sum_n D[o][n] * IN[q][n], and the bias
 *  G[woff + co*ci + o] = sum_n D[o][n]; rows o >= co_used (the 2x block's unused output
 *  units) are zero. Sums run in 4 interleaved lanes of 4, then pairwise, to keep the
 *  fp32 rounding near a tree sum's.
 *  NDRange: (ci + 1, co); work-item (ci, o) is the bias. */
__kernel void mlp_train_wgrad(__global const float *D, __global const float *IN,
                              __global float *G, int n_samples, int ci, int co, int co_used,
                              int woff)
{
    const int q = get_global_id(0), o = get_global_id(1);
    if (q > ci || o >= co)
        return;
    float4 acc0 = (float4)(0.0f), acc1 = (float4)(0.0f);
    if (o < co_used) {
        __global const float *d = D + (long)o * n_samples;
        __global const float *x = IN + (long)q * n_samples;
        const int n8 = n_samples & ~7;
        int n = 0;
        if (q < ci) {
            for (; n < n8; n += 8) {
                acc0 = fma(vload4(0, d + n), vload4(0, x + n), acc0);
                acc1 = fma(vload4(0, d + n + 4), vload4(0, x + n + 4), acc1);
            }
            for (; n < n_samples; ++n)
                acc0.s0 = fma(d[n], x[n], acc0.s0);
        } else {
            for (; n < n8; n += 8) {
                acc0 += vload4(0, d + n);
                acc1 += vload4(0, d + n + 4);
            }
            for (; n < n_samples; ++n)
                acc0.s0 += d[n];
        }
    }
    const float4 t = acc0 + acc1;
    const float sum = (t.s0 + t.s1) + (t.s2 + t.s3);
    G[woff + (q < ci ? o * ci + q : co * ci + o)] = sum;
}

/** torch.optim.Adam (no weight decay, not amsgrad), one parameter per work-item:
 *  m += (1 - beta1) (g - m); v = beta2 v + (1 - beta2) g^2;
 *  p -= lr / bc1 * m / (sqrt(v) / sqrt(bc2) + eps), bc = 1 - beta^t (host).
 *  NDRange: count rounded up; the kernel guards. */
__kernel void mlp_train_adam(__global float *wp, __global const float *G, __global float *M,
                             __global float *V, int count, float lr, float beta1, float beta2,
                             float eps, float bc1, float bc2_sqrt)
{
    const int k = get_global_id(0);
    if (k >= count)
        return;
    const float g = G[k];
    const float m = fma(1.0f - beta1, g - M[k], M[k]);
    const float v = fma(1.0f - beta2, g * g, beta2 * V[k]);
    M[k] = m;
    V[k] = v;
    wp[k] -= (lr / bc1) * m / (sqrt(v) / bc2_sqrt + eps);
}
