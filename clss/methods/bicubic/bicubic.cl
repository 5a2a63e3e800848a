/* The plain bicubic baseline's frame step around clss.ops.resize (the room
 * clss/methods/bicubic/; its ONNX twin oracle.py states the same formulas as graph nodes):
 *
 *   bicubic_encode  the caller's colour (image layout, float32 linear) -> PQ [3,h,w] (T)
 *   (resize)        Keys cubic, a = -0.75, half-pixel centres, on the PQ planes
 *   bicubic_decode  PQ [3,H,W] (T) -> the caller's image, linear (the code value clamped
 *                   to [0, 1] first, as the twin's Clip)
 */
#include "common.h"

#pragma OPENCL FP_CONTRACT OFF

#include "pq.h"

/** @param[in]  color        [h,w,3] float32 linear
 *  @param[out] x            [3,h,w] T: PQ code values of colour / exposure
 *  @param[in]  h            render height
 *  @param[in]  w            render width
 *  @param[in]  inv_exposure 1 / exposure
 *  @param[in]  pq_scale     nits / 10000
 *  NDRange: (w, h). */
__kernel void bicubic_encode(__global const float *color, __global T *x, int h, int w,
                             float inv_exposure, float pq_scale)
{
    const int px = get_global_id(0), py = get_global_id(1);
    if (px >= w || py >= h) return;
    const long plane = (long)h * w, p = (long)py * w + px;
    for (int c = 0; c < 3; ++c)
        ST(x, c * plane + p, pq_encode(color[3 * p + c] * inv_exposure, pq_scale));
}

/** @param[in]  y            [3,H,W] T: the resized PQ code values
 *  @param[out] out          [H,W,3] float32 linear
 *  @param[in]  H            output height
 *  @param[in]  W            output width
 *  @param[in]  inv_pq_scale 10000 / nits, times the exposure
 *  NDRange: (W, H). */
__kernel void bicubic_decode(__global const T *y, __global float *out, int H, int W,
                             float inv_pq_scale)
{
    const int X = get_global_id(0), Y = get_global_id(1);
    if (X >= W || Y >= H) return;
    const long plane = (long)H * W, p = (long)Y * W + X;
    for (int c = 0; c < 3; ++c)
        out[3 * p + c] = pq_decode(LD(y, c * plane + p), inv_pq_scale);
}

/* -DBICUBIC_FUSED=1 (fast path bicubic.fused8, CPU devices): the frame step in two passes
 * of 8 pixels of a row per work-item instead of three of one pixel, so that the PQ
 * transfer runs on float8 (PoCL calls its scalar exp2 and log2 out of line: the
 * per-pixel decode was three quarters of the step) and the resized PQ planes never go
 * through memory:
 *
 *   bicubic_encode8         the caller's colour -> PQ [3,h,w] (T), bicubic_encode's
 *                           operations on float8 lanes
 *   bicubic_resize_decode8  resize_x8's cubic (the same axis tables, operations and order,
 *                           the sum rounded to T as the resize's store would round it), the
 *                           clip and the PQ decode, written interleaved
 *
 * The float8 exp2 and log2 need not round as the scalar ones: checked against the
 * three-pass reference within the default tolerance. */
#ifndef BICUBIC_FUSED
#define BICUBIC_FUSED 0
#endif
#if BICUBIC_FUSED

/* -DSCALE2=1 (the host: an output of exactly twice the render size in both axes): away
 * from the edges a work-item's taps along x are one window of 8 inputs, loaded as one
 * vector and spread to the taps by shuffles (clang's, so PoCL only: CLSS_CLANG_VECTORS)
 * instead of 32 scalar loads per row and channel; the same elements, weights and sums. */
#ifndef SCALE2
#define SCALE2 0
#endif
#if SCALE2 && defined(__clang__) && CLSS_CLANG_VECTORS
#define WINDOW2 1
#else
#define WINDOW2 0
#endif

static PQ_ENCODE_C(float8, pq_encode8, powq8, pq_clamp8)

/* float8 of a float buffer, stored (XLD8's counterpart) */
#if defined(__clang__) && CLSS_CLANG_VECTORS
#define XST8(p, v) (*(__global Fv8u *)(p) = (v))
#else
#define XST8(p, v) vstore8((v), 0, (p))
#endif

/* a sum as the storage type T would hold it (the resize's store, then the decode's load) */
#if defined(CLSS_FP16) || defined(CLSS_FP16_NATIVE)
static float8 round_t8(float8 v)
{
#if defined(CLSS_FP16) && defined(__clang__) && CLSS_CLANG_VECTORS
    return __builtin_convertvector(__builtin_convertvector(v, Th8), float8);
#else
    ushort t[8];        /* no half variables without cl_khr_fp16; half pointers are fine */
    vstore_half8_rte(v, 0, (__private half *)t);
    return vload_half8(0, (__private const half *)t);
#endif
}
#else
#define round_t8(v) (v)
#endif

/** @param[in]  color        [h,w,3] float32 linear
 *  @param[out] x            [3,h,w] T: PQ code values of colour / exposure
 *  @param[in]  h            render height
 *  @param[in]  w            render width
 *  @param[in]  inv_exposure 1 / exposure
 *  @param[in]  pq_scale     nits / 10000
 *  @note -DBICUBIC_FUSED=1; -DCLSS_CLANG_VECTORS=0|1: builtin-free loads and stores
 *  NDRange: (ceil(w / 8), h); lanes past the row's end compute on its last pixel and are
 *  not stored. */
__kernel void bicubic_encode8(__global const float *color, __global T *x, int h, int w,
                              float inv_exposure, float pq_scale)
{
    const int j0 = get_global_id(0) * 8, i = get_global_id(1);
    if (j0 >= w || i >= h) return;
    const int n = min(8, w - j0);
    const long plane = (long)h * w, p = (long)i * w + j0;
    __global const float *src = color + 3 * p;
    float t[24];
    if (n == 8) {
        PST8(t, XLD8(src));
        PST8(t + 8, XLD8(src + 8));
        PST8(t + 16, XLD8(src + 16));
    } else {
        for (int k = 0; k < 24; ++k)
            t[k] = src[3 * min(k / 3, n - 1) + k % 3];
    }
    for (int c = 0; c < 3; ++c) {
        float v[8];
        for (int l = 0; l < 8; ++l)
            v[l] = t[3 * l + c];
        const float8 e = pq_encode8(PLD8(v) * inv_exposure, pq_scale);
        if (n == 8) {
            FST8(x, c * plane + p, e);
        } else {
            PST8(v, e);
            for (int l = 0; l < n; ++l)
                FST(x, c * plane + p + l, v[l]);
        }
    }
}

/** @param[in]  x            [3,h,w] T: the PQ planes (bicubic_encode8)
 *  @param[out] out          [H,W,3] float32 linear
 *  @param[in]  h            render height
 *  @param[in]  w            render width
 *  @param[in]  H            output height
 *  @param[in]  W            output width
 *  @param[in]  inv_pq_scale 10000 / nits, times the exposure
 *  @param[in]  idx          [(H + W) * 4] the cubic's edge-clamped tap indices (resize.cl's
 *                           axis_tables: rows, then columns)
 *  @param[in]  wt           [(H + W) * 4] its tap weights
 *  @note -DBICUBIC_FUSED=1; -DCLSS_CLANG_VECTORS=0|1: builtin-free loads and stores
 *  NDRange: (ceil(W / 8), H); a row's tail repeats its last column and is not stored. */
__kernel void bicubic_resize_decode8(__global const T *x, __global float *out, int h, int w,
                                     int H, int W, float inv_pq_scale,
                                     __global const int *idx, __global const float *wt)
{
    const int X0 = get_global_id(0) * 8, Y = get_global_id(1);
    if (X0 >= W || Y >= H) return;
    const int n = min(8, W - X0);
    const long plane = (long)h * w;
    float wy[4];
    int iy[4];
    for (int k = 0; k < 4; ++k) {
        wy[k] = wt[Y * 4 + k];
        iy[k] = idx[Y * 4 + k];
    }
    float wxa[4][8];
    int ix[4][8];
    for (int e = 0; e < 8; ++e) {
        const int o = H + X0 + min(e, n - 1);
        for (int k = 0; k < 4; ++k) {
            wxa[k][e] = wt[o * 4 + k];
            ix[k][e] = idx[o * 4 + k];
        }
    }
    float8 wx[4];
    for (int k = 0; k < 4; ++k)
        wx[k] = PLD8(wxa[k]);
#if WINDOW2
    /* output x = 2j and 2j + 1 take input taps j - 2 .. j + 1 and j - 1 .. j + 2: the 8
     * outputs from X0 = 4a * 2 read inputs 4a - 2 .. 4a + 5, tap k of output e at
     * 4a - 2 + ceil(e / 2) + k, which axis_tables gives wherever no tap is clamped */
    const int a0 = X0 / 2 - 2, inside = X0 >= 8 && X0 + 12 <= W;
#endif
    float d[3][8];
    for (int c = 0; c < 3; ++c) {
        float8 acc = (float8)(0.0f);
        for (int r = 0; r < 4; ++r) {
            __global const T *row = x + c * plane + (long)iy[r] * w;
            float8 racc = (float8)(0.0f);
#if WINDOW2
            if (inside) {
                const float8 v = FLD8(row, a0);
                racc += wx[0] * __builtin_shufflevector(v, v, 0, 1, 1, 2, 2, 3, 3, 4);
                racc += wx[1] * __builtin_shufflevector(v, v, 1, 2, 2, 3, 3, 4, 4, 5);
                racc += wx[2] * __builtin_shufflevector(v, v, 2, 3, 3, 4, 4, 5, 5, 6);
                racc += wx[3] * __builtin_shufflevector(v, v, 3, 4, 4, 5, 5, 6, 6, 7);
            } else
#endif
            for (int k = 0; k < 4; ++k) {
                float g[8];
                for (int e = 0; e < 8; ++e)
                    g[e] = (float)FLD(row, ix[k][e]);
                racc += wx[k] * PLD8(g);
            }
            acc += wy[r] * racc;
        }
        PST8(d[c], pq_decode8q(round_t8(acc), inv_pq_scale));
    }
    __global float *o = out + 3 * ((long)Y * W + X0);
    float t[24];
    for (int l = 0; l < 8; ++l)
        for (int c = 0; c < 3; ++c)
            t[3 * l + c] = d[c][l];
    if (n == 8) {
        XST8(o, PLD8(t));
        XST8(o + 8, PLD8(t + 8));
        XST8(o + 16, PLD8(t + 16));
    } else {
        for (int k = 0; k < 3 * n; ++k)
            o[k] = t[k];
    }
}
#endif
