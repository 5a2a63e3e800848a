/* mlp: a per-pixel chain of dense layers (1x1 convolutions) with fused
 * activations, all in one kernel; the hidden activations of a work-item's
 * pixels stay in private memory (registers, spilling to the stack) and
 * never touch global memory.
 *
 * The network is baked in at build time, so every loop over a layer's
 * inputs unrolls:
 *   -DNL=n                 number of layers (1..8)
 *   -DC0=, -DC1=, ... -DCn= widths: C0 input channels, Ck layer k's outputs
 *   -DACT1=, ...           layer k's activation (ACT_* ids of common.h)
 *   -DALPHA1=, ...         layer k's leaky_relu slope
 *   -DOFF1=, ...           layer k's offset in the packed weight buffer, which
 *                          holds per layer W [Ck][Ck-1] row-major, then b [Ck]
 *   -DCMAX=                the widest of C0..Cn (private array size)
 *   -DXV=1|2               A8 pixel vectors per work-item (tunable)
 *
 * x: [N, C0, H, W], y: [N, Cn, H, W]. NDRange: (ceil(H*W / (8*XV)), N).
 * Each work-item takes 8*XV consecutive pixels of one image; the image's last
 * block loads and stores element by element, inside the tensor.
 */
#include "common.h"

/* Without a network from the host (a porter building the source as is, or
 * `clss verify`'s build check), a 4 -> 4 single-layer ReLU network. */
#ifndef NL
#define NL 1
#define C0 4
#define C1 4
#define CMAX 4
#define ACT1 ACT_RELU
#define ALPHA1 0.0f
#define OFF1 0
#endif

#ifndef XV
#define XV 1
#endif
#ifndef OB
#define OB 4 /* outputs per pass over a layer's inputs: each input load feeds OB FMAs */
#endif

/* FLD/FLD8/FST/FST8 and TW/LDW (packed weights: float in fp16 storage mode,
 * rounded to half by the host, so the unrolled loops broadcast them without a
 * conversion each): kernels/common.h. */

/* Per-layer activation (common.h's APPLY_ACT serves one ACT per build).
 * relu/leaky_relu compare with < so that NaN passes through, as in onnxruntime. */
inline A8 act8(A8 v, int kind, float alpha)
{
    if (kind == ACT_RELU)
        return v < (A8)A_ZERO ? (A8)A_ZERO : v;
    if (kind == ACT_LEAKY_RELU)
        return v < (A8)A_ZERO ? v * (A)alpha : v;
    if (kind == ACT_SIGMOID)
        return SIGMOID(v);
    if (kind == ACT_TANH)
        return tanh(v);
    return v;
}

/* One dense layer: OUT[o] = act(b[o] + sum_i W[o][i] * IN[i]) for the
 * work-item's pixel vectors, OB outputs per pass so each IN[i] load feeds OB
 * multiply-adds; outputs past CO reuse row CO-1 (in bounds) and are dropped.
 * The accumulators live in registers; IN/OUT are indexed by loop counters and
 * so live in private memory (the stack, L1 on a CPU) either way, which is why
 * unrolling the input loop by 8 runs as fast as unrolling it fully and
 * compiles in a fraction of the time for 50- to 128-wide layers. */
#define LAYER(IN, OUT, CI, CO, WOFF, ACTK, ALPHAK)                             \
    for (int o = 0; o < (CO); o += OB) {                                       \
        A8 a[OB][XV];                                                          \
        int r[OB];                                                             \
        _Pragma("unroll") for (int j = 0; j < OB; ++j) {                       \
            r[j] = o + j < (CO) ? o + j : (CO) - 1;                            \
            const A b = LDW(wp, (WOFF) + (CO) * (CI) + r[j]);                  \
            for (int v = 0; v < XV; ++v)                                       \
                a[j][v] = (A8)b;                                               \
        }                                                                      \
        _Pragma("unroll 8") for (int i = 0; i < (CI); ++i)                     \
            _Pragma("unroll") for (int j = 0; j < OB; ++j) {                   \
                const A wv = LDW(wp, (WOFF) + r[j] * (CI) + i);                \
                for (int v = 0; v < XV; ++v)                                   \
                    a[j][v] += wv * IN[i][v];                                  \
            }                                                                  \
        _Pragma("unroll") for (int j = 0; j < OB; ++j)                         \
            if (o + j < (CO))                                                  \
                for (int v = 0; v < XV; ++v)                                   \
                    OUT[o + j][v] = act8(a[j][v], (ACTK), (ALPHAK));           \
    }

/** @param[in]  x    [N, C0, H, W] input
 *  @param[in]  wp   the packed weights: per layer k, W [Ck][Ck-1] row-major then b [Ck], at OFFk
 *  @param[out] y    [N, Cn, H, W] output
 *  @param[in]  HW   pixels per image (H * W)
 *  @note -DNL=n, -DC0..-DCn, -DACTk, -DALPHAk, -DOFFk, -DCMAX: the network, baked in (see the top of this file)
 *  @note -DXV=1|2: A8 pixel vectors per work-item (tunable)
 *  @note -DCLSS_FP16 / -DCLSS_FP16_NATIVE: the storage precision (common.h); T and TB follow it
 */
__kernel void mlp(__global const T *x, __global const TW *wp, __global T *y, int HW)
{
    const int pb = get_global_id(0), n = get_global_id(1);
    const int p0 = pb * 8 * XV;
    if (p0 >= HW)
        return;
    const int full = p0 + 8 * XV <= HW;
    A8 h0[CMAX][XV], h1[CMAX][XV];

    const __global T *xn = x + (long)n * C0 * HW;
    for (int c = 0; c < C0; ++c)
        for (int v = 0; v < XV; ++v) {
            const int p = p0 + 8 * v;
            if (full) {
                h0[c][v] = FLD8(xn, (long)c * HW + p);
            } else {
                union { A8 v; A e[8]; } u;
                for (int e = 0; e < 8; ++e)
                    u.e[e] = FLD(xn, (long)c * HW + (p + e < HW ? p + e : HW - 1));
                h0[c][v] = u.v;
            }
        }

    /* Layers alternate between h0 and h1. */
    LAYER(h0, h1, C0, C1, OFF1, ACT1, ALPHA1)
#if NL >= 2
    LAYER(h1, h0, C1, C2, OFF2, ACT2, ALPHA2)
#endif
#if NL >= 3
    LAYER(h0, h1, C2, C3, OFF3, ACT3, ALPHA3)
#endif
#if NL >= 4
    LAYER(h1, h0, C3, C4, OFF4, ACT4, ALPHA4)
#endif
#if NL >= 5
    LAYER(h0, h1, C4, C5, OFF5, ACT5, ALPHA5)
#endif
#if NL >= 6
    LAYER(h1, h0, C5, C6, OFF6, ACT6, ALPHA6)
#endif
#if NL >= 7
    LAYER(h0, h1, C6, C7, OFF7, ACT7, ALPHA7)
#endif
#if NL >= 8
    LAYER(h1, h0, C7, C8, OFF8, ACT8, ALPHA8)
#endif
#if NL > 8
#error "mlp: at most 8 layers per kernel (the host chains longer networks)"
#endif
#if NL % 2
#define OUTV h1
#else
#define OUTV h0
#endif
#define CN_(k) C##k
#define CN(k) CN_(k)

    __global T *yn = y + (long)n * CN(NL) * HW;
    for (int c = 0; c < CN(NL); ++c)
        for (int v = 0; v < XV; ++v) {
            const int p = p0 + 8 * v;
            if (full) {
                FST8(yn, (long)c * HW + p, OUTV[c][v]);
            } else {
                union { A8 v; A e[8]; } u;
                u.v = OUTV[c][v];
                for (int e = 0; e < 8 && p + e < HW; ++e)
                    FST(yn, (long)c * HW + p + e, u.e[e]);
            }
        }
}
