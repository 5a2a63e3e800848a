/* mlp_upscale: the shader MLP upscaler's frame step (seed 004, Spencer 2022;
 * docs/methods/mlp.md), two kernels:
 *
 *   mlp_upscale_blocks  per render pixel and colour channel: gather the 5x5 beauty
 *                       neighbourhood (render res, PQ-encoded) and the 5x5 feature
 *                       neighbourhood (output res depth), remove each one's mean (DC),
 *                       apply the gamma ramp, run the 50-50-50-25 MLP and write the
 *                       B x B output block back in the PQ domain (mean + inverse ramp);
 *   mlp_upscale_fold    per output pixel: the mean of the blocks that cover it, PQ
 *                       decode, exposure.
 *
 * The hidden activations stay in private memory; the blocks go through global memory
 * once ([3][B*B][h][w], storage type T), so that each output pixel averages its
 * overlapping blocks without atomics.
 *
 * Geometry and constants come from the host (clss/methods/mlp/transform.py, written
 * once for this kernel and the ONNX and torch twins):
 *   -DS=2|3            the integer scale
 *   -DB=S+2            output block side; block of render pixel (i, j) starts at output
 *                      pixel (S*i-1, S*j-1); unit k < B*B is its pixel (k / B, k % B)
 *   -DFEATURE=0|1      1: the feature pass feeds units 25..49; 0: they are zero (the
 *                      seed's ablation)
 *   -DINV_GAMMA, -DGAMMA, -DEPS, -DEPS_ROOT   the ramp sign(r)((|r|+EPS)^(1/GAMMA) - EPS_ROOT)
 *   -DALPHA            the hidden layers' leaky ReLU slope
 *   -DPQ_M1, -DPQ_M2, -DPQ_C1, -DPQ_C2, -DPQ_C3   the contract's PQ constants
 * Weights: float, per layer W [out][in] row-major then b [out] (fp16 storage mode: the
 * host rounds them to half first), layers 50->50, 50->50, 50->25.
 */
#include "common.h"

#include "mlp_layout.h"
/* the PQ transfer with the library pow (the seed's; its twins use ONNX Pow); without -D
 * options, pq.h's defaults are the contract's constants */
#include "pq.h"

inline PQ_ENCODE(float, mu_pq_encode, pow)
inline PQ_DECODE(float, mu_pq_decode, pow, fmax)

/* IN [CI] -> OUT [CO] = act(W IN + b); leaky when LEAKY. */
#define DENSE(IN, OUT, CI, CO, WOFF, LEAKY)                                  \
    for (int o = 0; o < (CO); ++o) {                                         \
        float a = wp[(WOFF) + (CO) * (CI) + o];                              \
        for (int q = 0; q < (CI); ++q)                                       \
            a = fma(wp[(WOFF) + o * (CI) + q], IN[q], a);                    \
        OUT[o] = (LEAKY) && a < 0.0f ? a * (float)ALPHA : a;                 \
    }

/** @param[in]  color         [h][w][3] linear colour (render res, the contract's layout)
 *  @param[in]  feat          [H][W] depth at output resolution (unused when FEATURE=0)
 *  @param[in]  wp            the packed weights (float), see the top of this file
 *  @param[out] blocks        [3][B*B][h][w] each render pixel's output block, PQ domain
 *  @param[in]  h, w, H, W    render and output sizes (H = S*h, W = S*w)
 *  @param[in]  inv_exposure  1 / exposure, applied before the PQ encode
 *  @param[in]  pq_scale      nits / 10000 (linear 1.0 in PQ units)
 *  @note -DS, -DB, -DFEATURE, -DGAMMA, -DINV_GAMMA, -DEPS, -DEPS_ROOT, -DALPHA, -DPQ_*: see the top of this file
 *  @note -DCLSS_FP16: half storage of color, feat and blocks (float arithmetic)
 *  NDRange: (w, h) rounded up to the work-group; the kernel guards. */
__kernel void mlp_upscale_blocks(__global const T *color, __global const T *feat,
                                 __global const float *wp, __global T *blocks,
                                 int h, int w, int H, int W, float inv_exposure,
                                 float pq_scale)
{
    const int j = get_global_id(0), i = get_global_id(1);
    if (j >= w || i >= h)
        return;
    float x[NI], h1[NH], h2[NH], y[NO];

#if FEATURE
    {
        float m = 0.0f;
        for (int dy = 0; dy < TAPS; ++dy) {
            const int yy = clamp(S * i - 1 + dy, 0, H - 1);
            for (int dx = 0; dx < TAPS; ++dx) {
                const int xx = clamp(S * j - 1 + dx, 0, W - 1);
                const float v = LD(feat, (long)yy * W + xx);
                x[NT + dy * TAPS + dx] = v;
                m += v;
            }
        }
        m *= 1.0f / NT;
        for (int k = 0; k < NT; ++k)
            x[NT + k] = mlp_ramp(x[NT + k] - m);
    }
#else
    for (int k = 0; k < NT; ++k)
        x[NT + k] = 0.0f;
#endif

    const long hw = (long)h * w;
    for (int c = 0; c < 3; ++c) {
        float m = 0.0f;
        for (int dy = 0; dy < TAPS; ++dy) {
            const int yy = clamp(i - 2 + dy, 0, h - 1);
            for (int dx = 0; dx < TAPS; ++dx) {
                const int xx = clamp(j - 2 + dx, 0, w - 1);
                const float v = mu_pq_encode(LD(color, ((long)yy * w + xx) * 3 + c) * inv_exposure,
                                             pq_scale);
                x[dy * TAPS + dx] = v;
                m += v;
            }
        }
        m *= 1.0f / NT;
        for (int k = 0; k < NT; ++k)
            x[k] = mlp_ramp(x[k] - m);

        DENSE(x, h1, NI, NH, OFF1, 1)
        DENSE(h1, h2, NH, NH, OFF2, 1)
        /* only the BB units the block uses (16 of 25 at 2x) */
        for (int o = 0; o < BB; ++o) {
            float a = wp[OFF3 + NO * NH + o];
            for (int q = 0; q < NH; ++q)
                a = fma(wp[OFF3 + o * NH + q], h2[q], a);
            y[o] = a;
        }
        for (int k = 0; k < BB; ++k)
            ST(blocks, ((long)c * BB + k) * hw + (long)i * w + j, m + mlp_ramp_inv(y[k]));
    }
}

/** @param[in]  blocks        [3][B*B][h][w] from mlp_upscale_blocks (PQ domain)
 *  @param[out] out           [H][W][3] linear colour
 *  @param[in]  h, w, H, W    render and output sizes
 *  @param[in]  exposure      applied after the PQ decode
 *  @param[in]  inv_pq_scale  10000 / nits
 *  @note -DS, -DB: as mlp_upscale_blocks; -DCLSS_FP16: half storage
 *  NDRange: (W, H) rounded up to the work-group; the kernel guards. */
__kernel void mlp_upscale_fold(__global const T *blocks, __global T *out, int h, int w,
                               int H, int W, float exposure, float inv_pq_scale)
{
    const int x = get_global_id(0), y = get_global_id(1);
    if (x >= W || y >= H)
        return;
    /* blocks i with S*i-1 <= y <= S*i+S: i = ihi or ihi-1, ihi = floor((y+1)/S) */
    const int ihi = (y + 1) / S, jhi = (x + 1) / S;
    const long hw = (long)h * w;
    float acc[3] = {0.0f, 0.0f, 0.0f};
    int n = 0;
    for (int i = ihi - 1; i <= ihi; ++i) {
        if (i < 0 || i >= h || S * i < y - S)
            continue;
        for (int j = jhi - 1; j <= jhi; ++j) {
            if (j < 0 || j >= w || S * j < x - S)
                continue;
            const int k = (y + 1 - S * i) * B + (x + 1 - S * j);
            for (int c = 0; c < 3; ++c)
                acc[c] += LD(blocks, ((long)c * BB + k) * hw + (long)i * w + j);
            ++n;
        }
    }
    const float inv_n = 1.0f / (float)n;
    for (int c = 0; c < 3; ++c)
        ST(out, ((long)y * W + x) * 3 + c, mu_pq_decode(acc[c] * inv_n, inv_pq_scale) * exposure);
}

/* ---- the fast path (-DVEC=8 or 16; fastpath.py registers it with
 * clss.selfcheck against the scalar kernels above) ----------------------------------------
 *
 *   mlp_upscale_pq        per render pixel: the PQ encode, once ([3][h][w] float planes),
 *                         not 25 times per neighbourhood as the reference kernel does;
 *   mlp_upscale_blocks_v  VEC horizontally adjacent render pixels per work-item, as the
 *                         lanes of floatVEC vectors: the weights are uniform scalars
 *                         broadcast across the lanes, so each multiply-add of the MLP is
 *                         one vector FMA; the feature half of the first layer is computed
 *                         once per pixel and shared by the three colour channels. */
#if defined(VEC) && VEC > 1
#if VEC == 16
typedef float16 VF;
#define VLOAD vload16
#define VSTORE vstore16
#define VSTORE_HALF vstore_half16_rte
#else
typedef float8 VF;
#define VLOAD vload8
#define VSTORE vstore8
#define VSTORE_HALF vstore_half8_rte
#endif

__kernel void mlp_upscale_pq(__global const T *color, __global float *pq, int h, int w,
                             float inv_exposure, float pq_scale)
{
    const int j = get_global_id(0), i = get_global_id(1);
    if (j >= w || i >= h)
        return;
    const long p = (long)i * w + j, hw = (long)h * w;
    for (int c = 0; c < 3; ++c)
        pq[c * hw + p] = mu_pq_encode(LD(color, p * 3 + c) * inv_exposure, pq_scale);
}

inline VF mv_ramp(VF r)
{
    return sign(r) * (pow(fabs(r) + (float)EPS, (VF)((float)INV_GAMMA)) - (float)EPS_ROOT);
}

inline VF mv_ramp_inv(VF y)
{
    return sign(y) * (pow(fabs(y) + (float)EPS_ROOT, (VF)((float)GAMMA)) - (float)EPS);
}

/* lanes of a gather: lane l reads EXPR with l bound. The vector is zeroed first: its
 * lanes are then written through a float pointer, which oclgrind's uninitialised-value
 * tracking does not follow (it reported every gathered vector as uninitialised). */
#define LANES(EXPR) ({ VF _v = (VF)(0.0f); float *_p = (float *)&_v;        \
    for (int l = 0; l < VEC; ++l) _p[l] = (EXPR); _v; })

/** @param[in]  pq      [3][h][w] from mlp_upscale_pq
 *  other parameters as mlp_upscale_blocks (no exposure: the PQ pass applied it)
 *  NDRange: (ceil(w / VEC), h) rounded up to the work-group; the kernel guards. */
__kernel void mlp_upscale_blocks_v(__global const float *pq, __global const T *feat,
                                   __global const float *wp, __global T *blocks,
                                   int h, int w, int H, int W)
{
    const int j0 = get_global_id(0) * VEC, i = get_global_id(1);
    if (j0 >= w || i >= h)
        return;
    const long hw = (long)h * w;
    VF f1[NH], x[NT], h1[NH], h2[NH];

    /* the feature half of layer 1 (+ its bias), shared by the three channels */
    {
#if FEATURE
        VF m = (VF)(0.0f);
        for (int dy = 0; dy < TAPS; ++dy) {
            const long row = (long)clamp(S * i - 1 + dy, 0, H - 1) * W;
            for (int dx = 0; dx < TAPS; ++dx) {
                const VF v = LANES(LD(feat, row + clamp(S * min(j0 + l, w - 1) - 1 + dx, 0, W - 1)));
                x[dy * TAPS + dx] = v;
                m += v;
            }
        }
        m *= 1.0f / NT;
        for (int k = 0; k < NT; ++k)
            x[k] = mv_ramp(x[k] - m);
        for (int o = 0; o < NH; ++o) {
            VF a = (VF)(wp[OFF1 + NH * NI + o]);
            for (int q = 0; q < NT; ++q)
                a = fma((VF)(wp[OFF1 + o * NI + NT + q]), x[q], a);
            f1[o] = a;
        }
#else
        for (int o = 0; o < NH; ++o)
            f1[o] = (VF)(wp[OFF1 + NH * NI + o]);
#endif
    }

    for (int c = 0; c < 3; ++c) {
        __global const float *pc = pq + c * hw;
        VF m = (VF)(0.0f);
        for (int dy = 0; dy < TAPS; ++dy) {
            const long row = (long)clamp(i - 2 + dy, 0, h - 1) * w;
            for (int dx = 0; dx < TAPS; ++dx) {
                VF v;
                if (j0 >= 2 && j0 + VEC + 2 <= w)       /* interior: one vector load */
                    v = VLOAD(0, pc + row + j0 - 2 + dx);
                else
                    v = LANES(pc[row + clamp(j0 + l - 2 + dx, 0, w - 1)]);
                x[dy * TAPS + dx] = v;
                m += v;
            }
        }
        m *= 1.0f / NT;
        for (int k = 0; k < NT; ++k)
            x[k] = mv_ramp(x[k] - m);

        /* five outputs at a time: each input vector loaded once per five FMAs, the
         * five accumulators in registers */
        for (int o = 0; o < NH; o += 5) {
            VF a0 = f1[o], a1 = f1[o + 1], a2 = f1[o + 2], a3 = f1[o + 3], a4 = f1[o + 4];
            __global const float *w0 = wp + OFF1 + o * NI;
            for (int q = 0; q < NT; ++q) {
                const VF xq = x[q];
                a0 = fma((VF)(w0[q]), xq, a0);
                a1 = fma((VF)(w0[NI + q]), xq, a1);
                a2 = fma((VF)(w0[2 * NI + q]), xq, a2);
                a3 = fma((VF)(w0[3 * NI + q]), xq, a3);
                a4 = fma((VF)(w0[4 * NI + q]), xq, a4);
            }
            /* leaky ReLU, 0 < ALPHA < 1 */
            h1[o] = fmax(a0, a0 * (float)ALPHA);
            h1[o + 1] = fmax(a1, a1 * (float)ALPHA);
            h1[o + 2] = fmax(a2, a2 * (float)ALPHA);
            h1[o + 3] = fmax(a3, a3 * (float)ALPHA);
            h1[o + 4] = fmax(a4, a4 * (float)ALPHA);
        }
        for (int o = 0; o < NH; o += 5) {
            __global const float *w0 = wp + OFF2 + o * NH, *b0 = wp + OFF2 + NH * NH + o;
            VF a0 = (VF)(b0[0]), a1 = (VF)(b0[1]), a2 = (VF)(b0[2]), a3 = (VF)(b0[3]),
               a4 = (VF)(b0[4]);
            for (int q = 0; q < NH; ++q) {
                const VF xq = h1[q];
                a0 = fma((VF)(w0[q]), xq, a0);
                a1 = fma((VF)(w0[NH + q]), xq, a1);
                a2 = fma((VF)(w0[2 * NH + q]), xq, a2);
                a3 = fma((VF)(w0[3 * NH + q]), xq, a3);
                a4 = fma((VF)(w0[4 * NH + q]), xq, a4);
            }
            h2[o] = fmax(a0, a0 * (float)ALPHA);
            h2[o + 1] = fmax(a1, a1 * (float)ALPHA);
            h2[o + 2] = fmax(a2, a2 * (float)ALPHA);
            h2[o + 3] = fmax(a3, a3 * (float)ALPHA);
            h2[o + 4] = fmax(a4, a4 * (float)ALPHA);
        }
        /* the output layer: four units at a time (B*B = 16 or 25: a last single one) */
        for (int o0 = 0; o0 < BB; o0 += 4) {
            const int nb = min(4, BB - o0);
            __global const float *w0 = wp + OFF3 + o0 * NH, *b0 = wp + OFF3 + NO * NH + o0;
            VF acc[4];
            if (nb == 4) {
                VF a0 = (VF)(b0[0]), a1 = (VF)(b0[1]), a2 = (VF)(b0[2]), a3 = (VF)(b0[3]);
                for (int q = 0; q < NH; ++q) {
                    const VF xq = h2[q];
                    a0 = fma((VF)(w0[q]), xq, a0);
                    a1 = fma((VF)(w0[NH + q]), xq, a1);
                    a2 = fma((VF)(w0[2 * NH + q]), xq, a2);
                    a3 = fma((VF)(w0[3 * NH + q]), xq, a3);
                }
                acc[0] = a0; acc[1] = a1; acc[2] = a2; acc[3] = a3;
            } else {
                for (int u = 0; u < nb; ++u) {
                    VF a = (VF)(b0[u]);
                    for (int q = 0; q < NH; ++q)
                        a = fma((VF)(w0[u * NH + q]), h2[q], a);
                    acc[u] = a;
                }
            }
          for (int u = 0; u < nb; ++u) {
            const int o = o0 + u;
            const VF a = acc[u];
            const VF v = m + mv_ramp_inv(a);
            const long base = ((long)c * BB + o) * hw + (long)i * w + j0;
            if (j0 + VEC <= w) {
#if defined(CLSS_FP16) || defined(CLSS_FP16_NATIVE)
                VSTORE_HALF(v, 0, blocks + base);
#else
                VSTORE(v, 0, blocks + base);
#endif
            } else {
                const float *pv = (const float *)&v;
                for (int l = 0; l < w - j0; ++l)
                    ST(blocks, base + l, pv[l]);
            }
          }
        }
    }
}
#endif
