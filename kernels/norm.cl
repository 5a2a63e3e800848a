/* Normalisations over contiguous rows: ONNX LayerNormalization, InstanceNormalization and
 * GroupNormalization, one kernel.
 *
 * The host views the input as [rows, L], each row one normalisation group (LayerNorm: the
 * axes from `axis` on; InstanceNorm: one (n, c) image; GroupNorm: one (n, group) stack of
 * channels), all contiguous. One work-item per row, NDRange (rows): it takes the mean and
 * the variance in one pass over the values shifted by the row's first, then writes
 *   y = (x - mean) / sqrt(var + eps) * scale[s] + bias[s],
 * where s, the scale/bias element of row r's element j, is
 *   s = (r % SR) * SA + (j / SD) % SM
 * LayerNorm: SR=1, SA=0, SD=1, SM=L (s = j); InstanceNorm: SR=C, SA=1, SD=L, SM=1 (s = c);
 * GroupNorm: SR=G, SA=C/G, SD=H*W, SM=C/G (s = the channel). Sums are in float per row of
 * eight lanes.
 *
 * Build options:
 *   -DHAS_BIAS=0|1   add bias
 *   -DSCALE_MODE=0|1|2  0: the formula above; 1: s = j (LayerNorm); 2: s is the same for
 *                    the whole row (InstanceNorm; GroupNorm with a scale per group), folded
 *                    into one multiply-add per element
 *   -DCLSS_CLANG_VECTORS=0|1  loads and stores through common.h's FLD8/FST8 as clang
 *                    vector accesses (1, on PoCL) or the builtins
 *   -DSTATS=0|1      also write the row's mean and 1/sqrt(var + eps) (LayerNorm's optional
 *                    outputs Mean and InvStdDev)
 */
#include "common.h"

#ifndef HAS_BIAS
#define HAS_BIAS 1
#endif
#ifndef STATS
#define STATS 0
#endif
#ifndef SCALE_MODE
#define SCALE_MODE 0
#endif

/** @param[in]  in     [rows, L] input
 *  @param[in]  scale  scale, indexed as above
 *  @param[in]  bias   bias, indexed as scale (read with -DHAS_BIAS=1)
 *  @param[out] out    [rows, L] output
 *  @param[out] mean   [rows] row means (written with -DSTATS=1)
 *  @param[out] istd   [rows] 1 / sqrt(var + eps) (written with -DSTATS=1)
 *  @param[in]  L      elements per row
 *  @param[in]  rows   rows
 *  @param[in]  SR, SA, SD, SM  how a row and element index the scale (above)
 *  @param[in]  eps    epsilon
 *  @note -DHAS_BIAS=0|1; -DSTATS=0|1; -DSCALE_MODE=0|1|2; -DCLSS_CLANG_VECTORS=0|1
 *  @note -DCLSS_FP16 / -DCLSS_FP16_NATIVE: the storage precision (common.h); T and TB follow it
 */
__kernel void norm_rows(__global const T *in, __global const T *scale, __global const T *bias,
                        __global T *out, __global T *mean, __global T *istd, int L, int rows,
                        int SR, int SA, int SD, int SM, float eps)
{
    const int r = get_global_id(0);
    if (r >= rows) return;
    __global const T *x = in + (long)r * L;
    __global T *y = out + (long)r * L;
    /* mean and variance in one pass, of the values shifted by the row's first (the
     * shifted-data variance: no E[x^2] - E[x]^2 cancellation while the row's spread is not
     * tiny against its distance from that first value) */
    const float K = L > 0 ? (float)FLD(x, 0) : 0.0f;
    int j = 0;
    float8 s8 = (float8)(0.0f), q8 = (float8)(0.0f);
    while (j + 8 <= L) {    /* sums of blocks of up to 4096, then of the blocks: a long row
                             * (InstanceNorm's 1080p plane) adds 500 partial sums, not 2 M */
        const int end = min(L - 7, j + 4096);
        float8 bs = (float8)(0.0f), bq = (float8)(0.0f);
        for (; j < end; j += 8) {
            const float8 d = convert_float8(FLD8(x, j)) - K;
            bs += d;
            bq += d * d;
        }
        s8 += bs;
        q8 += bq;
    }
    float s = ((s8.s0 + s8.s1) + (s8.s2 + s8.s3)) + ((s8.s4 + s8.s5) + (s8.s6 + s8.s7));
    float q = ((q8.s0 + q8.s1) + (q8.s2 + q8.s3)) + ((q8.s4 + q8.s5) + (q8.s6 + q8.s7));
    for (; j < L; ++j) {
        const float d = (float)FLD(x, j) - K;
        s += d;
        q += d * d;
    }
    const float ds = s / (float)L;
    const float mu = K + ds;
    const float var = fmax(q / (float)L - ds * ds, 0.0f);
    const float inv = 1.0f / sqrt(var + eps);
#if STATS
    ST(mean, r, mu);
    ST(istd, r, inv);
#endif
    const long s0 = (long)(r % SR) * SA;
#if SCALE_MODE == 2
    /* one scale and bias for the whole row (InstanceNorm, GroupNorm's per-group form) */
    const float a = inv * (float)LD(scale, s0);
#if HAS_BIAS
    const float b = (float)LD(bias, s0) - mu * a;
#else
    const float b = -mu * a;
#endif
    for (j = 0; j + 8 <= L; j += 8)
        FST8(y, j, CONVERT_A8(convert_float8(FLD8(x, j)) * a + b));
    for (; j < L; ++j)
        FST(y, j, (float)FLD(x, j) * a + b);
#elif SCALE_MODE == 1
    /* LayerNorm: the scale and bias run along the row */
    for (j = 0; j + 8 <= L; j += 8) {
        float8 v = (convert_float8(FLD8(x, j)) - mu) * inv * convert_float8(FLD8(scale, j));
#if HAS_BIAS
        v += convert_float8(FLD8(bias, j));
#endif
        FST8(y, j, CONVERT_A8(v));
    }
    for (; j < L; ++j) {
        float v = ((float)FLD(x, j) - mu) * inv * (float)FLD(scale, j);
#if HAS_BIAS
        v += (float)FLD(bias, j);
#endif
        FST(y, j, v);
    }
#else
    for (j = 0; j < L; ++j) {
        const long si = s0 + (j / SD) % SM;
        float v = ((float)LD(x, j) - mu) * inv * (float)LD(scale, si);
#if HAS_BIAS
        v += (float)LD(bias, si);
#endif
        ST(y, j, v);
    }
#endif
}

/* Normalisation over a block of axes that is not the last: a [outer, L, inner] view
 * normalised along L for each (outer, inner) pair, as a channel LayerNorm of NCHW
 * (NAFNet's and ConvNeXt's LayerNorm2d: mean and variance over C at each pixel) exports.
 * One work-item per pair, NDRange (inner, outer): neighbouring work-items read
 * neighbouring pixels. y = (x - mean) / sqrt(var + eps) * scale[k] + bias[k]. */
/** @param[in]  in     [outer, L, inner] input
 *  @param[in]  scale  [L] scale
 *  @param[in]  bias   [L] bias (read with -DHAS_BIAS=1)
 *  @param[out] out    [outer, L, inner] output
 *  @param[in]  L      length of the normalised block
 *  @param[in]  inner  elements after it (NDRange dimension 0)
 *  @param[in]  outer  elements before it (NDRange dimension 1)
 *  @param[in]  eps    epsilon
 *  @note -DHAS_BIAS=0|1; -DCLSS_CLANG_VECTORS=0|1
 *  @note -DCLSS_FP16 / -DCLSS_FP16_NATIVE: the storage precision (common.h); T and TB follow it
 */
__kernel void norm_strided(__global const T *in, __global const T *scale, __global const T *bias,
                           __global T *out, int L, int inner, int outer, float eps)
{
    const int j = get_global_id(0), o = get_global_id(1);
    if (j >= inner || o >= outer) return;
    const long base = (long)o * L * inner + j;
    const float K = L > 0 ? (float)FLD(in, base) : 0.0f;   /* shifted sums, as norm_rows */
    float s = 0.0f, q = 0.0f;
    for (int k = 0; k < L; ++k) {
        const float d = (float)FLD(in, base + (long)k * inner) - K;
        s += d;
        q += d * d;
    }
    const float ds = s / (float)L;
    const float mu = K + ds;
    const float inv = 1.0f / sqrt(fmax(q / (float)L - ds * ds, 0.0f) + eps);
    for (int k = 0; k < L; ++k) {
        const long i = base + (long)k * inner;
        float v = ((float)FLD(in, i) - mu) * inv * (float)FLD(scale, k);
#if HAS_BIAS
        v += (float)FLD(bias, k);
#endif
        FST(out, i, v);
    }
}
