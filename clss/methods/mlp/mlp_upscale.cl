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
inline PQ_DECODE(float, mu_pq_decode, pow, fmax, clamp)

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

/* ---- the fused fast path (-DFUSED=1 -DVEC=8|16; fastpath.py registers it with
 * clss.selfcheck against the reference pair mlp_upscale_blocks + mlp_upscale_fold) -------
 *
 *   mlp_upscale_pq_v     per VEC render pixels: the PQ encode into [3][h][w] float planes
 *                        (exp2/log2 on whole vectors);
 *   mlp_upscale_fused    the MLP as a GEMM whose M dimension is the render pixels: VEC
 *                        horizontally adjacent blocks are the lanes of a vector, each weight
 *                        a scalar broadcast into the FMAs, K outputs at a time in registers;
 *                        the fold in the same kernel: a work-item walks `rows` block rows
 *                        down, the lanes of one block row are folded with the next lane by a
 *                        lane shift, the rows with the previous row's bottom held in private
 *                        memory; each output pixel is written once, PQ-decoded.
 *
 * Ownership: block (i, j) owns the output pixels (S*i+1 .. S*i+S, S*j+1 .. S*j+S); those
 * are covered by blocks i, i+1 and j, j+1 only, so that lane l (block j0+l) owns its S
 * columns with lane l+1's help: VEC lanes own VEC-1 blocks and the last lane is computed
 * for its neighbour's sake. Block -1 (outside the frame, masked to zero) owns output row
 * and column 0. The gamma ramp at GAMMA = 2 is a square root and a square (the same values
 * as pow to an ulp), with no library call among the vector registers. */
#if defined(FUSED) && defined(VEC) && VEC > 1
#pragma OPENCL FP_CONTRACT ON
typedef float FV __attribute__((ext_vector_type(VEC)));
typedef float FVu __attribute__((ext_vector_type(VEC), aligned(4)));
typedef int IV __attribute__((ext_vector_type(VEC)));

/* lane l <- lane l+1, the last lane zero; lane by lane (the optimiser makes it one
 * shuffle): oclgrind's uninitialised-value tracking reports every __builtin_shufflevector */
inline FV fu_lshift(FV v)
{
    FV r = (FV)(0.0f);
    _Pragma("unroll") for (int l = 0; l < VEC - 1; ++l)
        r[l] = v[l + 1];
    return r;
}
#define LSHIFT(v) fu_lshift(v)

/* |x| and sign by selects: no builtin calls */
#define FABS(x) ((x) < 0.0f ? -(x) : (x))

/* exp2, log2 and sqrt on 16 lanes as two 8-lane halves: pip's PoCL 3.0 (LLVM 14) on an
 * AVX-512 EPYC segfaulted compiling them on whole 16-lane vectors (the self-check turned
 * the fused path off there); halves vectorise the same on every compiler */
inline FV fu_exp2_scaled(float y, FV x)
{
#if VEC == 16
    FV r;
    r.lo = exp2(y * log2(x.lo));
    r.hi = exp2(y * log2(x.hi));
    return r;
#else
    return exp2(y * log2(x));
#endif
}
inline FV fu_sqrt(FV a)
{
#if VEC == 16
    FV r;
    r.lo = sqrt(a.lo);
    r.hi = sqrt(a.hi);
    return r;
#else
    return sqrt(a);
#endif
}

inline FV fu_ramp(FV r)
{
    const FV a = FABS(r) + (float)EPS;
    FV mag;
    if ((float)GAMMA == 2.0f)
        mag = fu_sqrt(a) - (float)EPS_ROOT;
    else
        mag = fu_exp2_scaled((float)INV_GAMMA, a) - (float)EPS_ROOT;
    return r > 0.0f ? mag : (r < 0.0f ? -mag : (FV)(0.0f));
}

inline FV fu_ramp_inv(FV y)
{
    const FV a = FABS(y) + (float)EPS_ROOT;
    FV mag;
    if ((float)GAMMA == 2.0f)
        mag = a * a - (float)EPS;
    else
        mag = fu_exp2_scaled((float)GAMMA, a) - (float)EPS;
    return y > 0.0f ? mag : (y < 0.0f ? -mag : (FV)(0.0f));
}

/* x^y for x >= 0 (0 at 0), whole vectors: exp2/log2 vectorise */
inline FV fu_pow(FV x, float y)
{
    return x > 0.0f ? fu_exp2_scaled(y, x) : (FV)(0.0f);
}

inline FV fu_clamp01(FV x)
{
    return x < 0.0f ? (FV)(0.0f) : (x > 1.0f ? (FV)(1.0f) : x);
}

inline FV fu_pq_encode(FV x, float pq_scale)
{
    const FV y = fu_clamp01(x * pq_scale);
    const FV ym = fu_pow(y, (float)PQ_M1);
    return fu_pow((PQ_C1 + PQ_C2 * ym) / (1.0f + PQ_C3 * ym), (float)PQ_M2);
}

inline FV fu_pq_decode(FV e, float inv_pq_scale)
{
    const FV ep = fu_pow(fu_clamp01(e), 1.0f / (float)PQ_M2);
    const FV d = ep - PQ_C1;
    return fu_pow((d < 0.0f ? (FV)(0.0f) : d) / (PQ_C2 - PQ_C3 * ep), 1.0f / (float)PQ_M1)
           * inv_pq_scale;
}

/** @param[in]  color  [h][w][3] linear colour
 *  @param[out] pq     [3][h][w] PQ-encoded planes (float)
 *  NDRange: (ceil(w / VEC), h) rounded up to the work-group; the kernel guards. */
__kernel void mlp_upscale_pq_v(__global const T *color, __global float *pq, int h, int w,
                               float inv_exposure, float pq_scale)
{
    const int j0 = get_global_id(0) * VEC, i = get_global_id(1);
    if (j0 >= w || i >= h)
        return;
    const long p0 = (long)i * w + j0, hw = (long)h * w;
    const int n = min(VEC, w - j0);
    for (int c = 0; c < 3; ++c) {
        FV v = (FV)(0.0f);
        for (int l = 0; l < n; ++l)
            v[l] = FLD(color, (p0 + l) * 3 + c);
        v = fu_pq_encode(v * inv_exposure, pq_scale);
        if (n == VEC) {
            *(__global FVu *)(pq + c * hw + p0) = v;
        } else {
            for (int l = 0; l < n; ++l)
                pq[c * hw + p0 + l] = v[l];
        }
    }
}

/* K outputs of a dense layer at a time: ACC[k] += W[k][q] * IN[q] for q < NIN, the weight
 * a broadcast scalar at a compile-time offset from WB + q (row stride STRIDE). The q loop
 * is not unrolled: unrolled, the scheduler computes one output after the other (one
 * accumulator, a chain of dependent FMAs at the FMA latency) to save registers; a loop
 * iteration keeps the K independent accumulators in flight. */
#define FU_GEMM(ACC, K, WB, STRIDE, IN, NIN)                                  \
    _Pragma("nounroll") for (int q = 0; q < (NIN); ++q) {                     \
        const FV xq = IN[q];                                                  \
        _Pragma("unroll") for (int k = 0; k < (K); ++k)                       \
            ACC[k] = (FV)((WB)[k * (STRIDE) + q]) * xq + ACC[k];              \
    }

#define FU_K 10          /* hidden outputs per register tile (50 = 5 x 10) */
#if BB % 8 == 0
#define FU_K3 8
#else
#define FU_K3 5
#endif

/* Store one output row's S column classes of one channel: V[t] the sums, INV[t] the
 * reciprocal counts (lanes), y the output row. */
#define FU_STORE_ROW(V, INV, VSCALE, yy)                                         \
    if ((yy) >= 0 && (yy) < H) {                                                 \
        for (int t = 0; t < S; ++t) {                                            \
            const FV lin = fu_pq_decode(V[t] * (INV[t] * (VSCALE)), inv_pq_scale) \
                           * exposure;                                           \
            __global T *orow = out + (long)(yy) * W * 3 + c;                     \
            for (int l = 0; l < VEC - 1; ++l) {                                  \
                const int xx = S * (jb0 + l) + 1 + t;                            \
                if (xx >= 0 && xx < W)                                           \
                    FST(orow, (long)xx * 3, lin[l]);                             \
            }                                                                    \
        }                                                                        \
    }

/** @param[in]  pq            [3][h][w] from mlp_upscale_pq_v
 *  @param[in]  feat          [H][W] depth at output resolution (unused when FEATURE=0)
 *  @param[in]  wp            the packed weights (float)
 *  @param[out] out           [H][W][3] linear colour
 *  @param[in]  h, w, H, W    render and output sizes
 *  @param[in]  rows          block rows a work-item owns
 *  @param[in]  exposure      applied after the PQ decode
 *  @param[in]  inv_pq_scale  10000 / nits
 *  NDRange: (ceil((w + 1) / (VEC - 1)), ceil((h + 1) / rows)); any work-group. */
__kernel void mlp_upscale_fused(__global const float *pq, __global const T *feat,
                                __global const float *wp, __global T *out,
                                int h, int w, int H, int W, int rows, float exposure,
                                float inv_pq_scale)
{
    const int jb0 = (int)get_global_id(0) * (VEC - 1) - 1;
    const int ib0 = (int)get_global_id(1) * rows - 1;
    if (jb0 >= w || ib0 >= h)
        return;
    const long hw = (long)h * w;

    /* lane masks and the reciprocal counts of the S column classes */
    FV lm = (FV)(0.0f), inv_h[S];
    {
        for (int l = 0; l < VEC; ++l)
            lm[l] = (jb0 + l >= 0 && jb0 + l < w) ? 1.0f : 0.0f;
        const FV both = lm + LSHIFT(lm);
        for (int t = 0; t < S; ++t)
            inv_h[t] = 1.0f / (t >= S - 2 ? both : lm);
    }
    /* lane l reads the clamped block column (blocks outside the frame are masked out) */
    const int interior = jb0 >= 2 && jb0 + VEC + 2 <= w;

    FV carry[3][2][S];          /* the previous block row's unit rows S and S+1, folded */
    float carry_valid = 0.0f;
    FV f1[NH], x[NT], h1[NH], h2[NH], vb[BB], hr[B][S];

    for (int ib = ib0; ib <= ib0 + rows; ++ib) {
        const int valid = ib >= 0 && ib < h;
        const float rv = valid ? 1.0f : 0.0f;
        const int owned = ib < ib0 + rows;
        if (valid) {
            /* the feature half of layer 1 (+ bias), shared by the three channels */
#if FEATURE
            {
                FV m = (FV)(0.0f);
                for (int dy = 0; dy < TAPS; ++dy) {
                    const long row = (long)clamp(S * ib - 1 + dy, 0, H - 1) * W;
                    for (int dx = 0; dx < TAPS; ++dx) {
                        FV v = (FV)(0.0f);
                        for (int l = 0; l < VEC; ++l)
                            v[l] = FLD(feat, row + clamp(S * clamp(jb0 + l, 0, w - 1) - 1 + dx,
                                                          0, W - 1));
                        x[dy * TAPS + dx] = v;
                        m += v;
                    }
                }
                m *= 1.0f / NT;
                for (int k = 0; k < NT; ++k)
                    x[k] = fu_ramp(x[k] - m);
                _Pragma("nounroll") for (int o = 0; o < NH; o += FU_K) {
                    FV a[FU_K];
                    __global const float *w0 = wp + OFF1 + o * NI + NT;
                    _Pragma("unroll") for (int k = 0; k < FU_K; ++k)
                        a[k] = (FV)(wp[OFF1 + NH * NI + o + k]);
                    FU_GEMM(a, FU_K, w0, NI, x, NT)
                    _Pragma("unroll") for (int k = 0; k < FU_K; ++k)
                        f1[o + k] = a[k];
                }
            }
#else
            for (int o = 0; o < NH; ++o)
                f1[o] = (FV)(wp[OFF1 + NH * NI + o]);
#endif
        }

        for (int c = 0; c < 3; ++c) {
            if (valid) {
                __global const float *pc = pq + c * hw;
                FV m = (FV)(0.0f);
                for (int dy = 0; dy < TAPS; ++dy) {
                    const long row = (long)clamp(ib - 2 + dy, 0, h - 1) * w;
                    for (int dx = 0; dx < TAPS; ++dx) {
                        FV v;
                        if (interior) {
                            v = *(__global const FVu *)(pc + row + jb0 - 2 + dx);
                        } else {
                            v = (FV)(0.0f);
                            for (int l = 0; l < VEC; ++l)
                                v[l] = pc[row + clamp(jb0 + l - 2 + dx, 0, w - 1)];
                        }
                        x[dy * TAPS + dx] = v;
                        m += v;
                    }
                }
                m *= 1.0f / NT;
                for (int k = 0; k < NT; ++k)
                    x[k] = fu_ramp(x[k] - m);

                _Pragma("nounroll") for (int o = 0; o < NH; o += FU_K) {
                    FV a[FU_K];
                    __global const float *w0 = wp + OFF1 + o * NI;
                    _Pragma("unroll") for (int k = 0; k < FU_K; ++k)
                        a[k] = f1[o + k];
                    FU_GEMM(a, FU_K, w0, NI, x, NT)
                    _Pragma("unroll") for (int k = 0; k < FU_K; ++k)
                        h1[o + k] = a[k] < 0.0f ? a[k] * (float)ALPHA : a[k];
                }
                _Pragma("nounroll") for (int o = 0; o < NH; o += FU_K) {
                    FV a[FU_K];
                    __global const float *w0 = wp + OFF2 + o * NH;
                    _Pragma("unroll") for (int k = 0; k < FU_K; ++k)
                        a[k] = (FV)(wp[OFF2 + NH * NH + o + k]);
                    FU_GEMM(a, FU_K, w0, NH, h1, NH)
                    _Pragma("unroll") for (int k = 0; k < FU_K; ++k)
                        h2[o + k] = a[k] < 0.0f ? a[k] * (float)ALPHA : a[k];
                }
                _Pragma("nounroll") for (int o = 0; o < BB; o += FU_K3) {
                    FV a[FU_K3];
                    __global const float *w0 = wp + OFF3 + o * NH;
                    _Pragma("unroll") for (int k = 0; k < FU_K3; ++k)
                        a[k] = (FV)(wp[OFF3 + NO * NH + o + k]);
                    FU_GEMM(a, FU_K3, w0, NH, h2, NH)
                    _Pragma("unroll") for (int k = 0; k < FU_K3; ++k)
                        vb[o + k] = (m + fu_ramp_inv(a[k])) * lm;
                }
                /* fold each unit row with the next lane's block: column class t of lane
                 * l is output column S*j+1+t, unit t+2 of its block and, for t >= S-2,
                 * unit t+2-S of block j+1 */
                for (int r = 0; r < B; ++r)
                    for (int t = 0; t < S; ++t)
                        hr[r][t] = t >= S - 2 ? vb[r * B + t + 2] + LSHIFT(vb[r * B + t + 2 - S])
                                              : vb[r * B + t + 2];
            } else {
                for (int r = 0; r < B; ++r)
                    for (int t = 0; t < S; ++t)
                        hr[r][t] = (FV)(0.0f);
            }

            /* rows S*ib-1 and S*ib: the previous block row's units S, S+1 and this one's
             * units 0, 1 */
            if (ib > ib0) {
                const float vs = 1.0f / (carry_valid + rv);
                for (int k = 0; k < 2; ++k) {
                    FV sum[S];
                    for (int t = 0; t < S; ++t)
                        sum[t] = carry[c][k][t] + hr[k][t];
                    FU_STORE_ROW(sum, inv_h, vs, S * ib - 1 + k)
                }
            }
            if (owned) {
                /* rows S*ib+1 .. S*ib+S-2: this block row alone */
                for (int k = 2; k < S; ++k)
                    FU_STORE_ROW(hr[k], inv_h, 1.0f, S * ib - 1 + k)
                for (int k = 0; k < 2; ++k)
                    for (int t = 0; t < S; ++t)
                        carry[c][k][t] = hr[S + k][t];
            }
        }
        carry_valid = rv;
    }
}
#endif
