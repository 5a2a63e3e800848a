/* The bilinear taps of a backward warp (the frame kernels' history warps): the sample at (xs, ys) in
 * index coordinates of a W x H grid, zero padding per tap as ONNX GridSample
 * padding_mode="zeros" (the twins' warps). Include after `#pragma OPENCL FP_CONTRACT OFF`:
 * the weights are plain products, as the twins compute them. */
#ifndef CLSS_WARP_TAPS_H
#define CLSS_WARP_TAPS_H

#include "inline_math.h"

/* One tap's weight wx * wy, 0 where the tap lies outside the grid. */
static float tap_w(int xi, int yi, int W, int H, float wx, float wy)
{
    return (xi >= 0 && xi < W && yi >= 0 && yi < H) ? wx * wy : 0.0f;
}

typedef struct {
    float w00, w10, w01, w11;   /* weights of (x0, y0), (x0+1, y0), (x0, y0+1), (x0+1, y0+1) */
    int cx0, cx1, cy0, cy1;     /* their clamped addresses: a tap of weight 0 reads a valid pixel */
} WarpTaps;

/* One body for the scalar taps and the float8 ones below: F the coordinate type, I its
 * integer type, TAPS the result, with their floor, int-to-float, tap weight and clamp. */
#define WARP_TAPS_FN(NAME, TAPS, F, I, FLOORI, TOF, TAPW, CLAMPI)                 \
    static TAPS NAME(F xs, F ys, int W, int H)                                    \
    {                                                                             \
        TAPS t;                                                                   \
        const I x0 = FLOORI(xs), y0 = FLOORI(ys);                                 \
        const F ax = xs - TOF(x0), ay = ys - TOF(y0);                             \
        t.w00 = TAPW(x0, y0, W, H, 1.0f - ax, 1.0f - ay);                         \
        t.w10 = TAPW(x0 + 1, y0, W, H, ax, 1.0f - ay);                            \
        t.w01 = TAPW(x0, y0 + 1, W, H, 1.0f - ax, ay);                            \
        t.w11 = TAPW(x0 + 1, y0 + 1, W, H, ax, ay);                               \
        t.cx0 = CLAMPI(x0, 0, W - 1);                                             \
        t.cx1 = CLAMPI(x0 + 1, 0, W - 1);                                         \
        t.cy0 = CLAMPI(y0, 0, H - 1);                                             \
        t.cy1 = CLAMPI(y0 + 1, 0, H - 1);                                         \
        return t;                                                                 \
    }

#define CLSS_TOF1(x) ((float)(x))
WARP_TAPS_FN(warp_taps, WarpTaps, float, int, clss_floori, CLSS_TOF1, tap_w, clss_clampi)

/* The same taps for 8 samples at once (float8 lanes; the frame kernels' 8-pixel work-items):
 * the same operations lane by lane, so each lane equals warp_taps of its sample. */
typedef struct {
    float8 w00, w10, w01, w11;
    int8 cx0, cx1, cy0, cy1;
} WarpTaps8;

/* Conversions and selects as clang's vector operations where it is the compiler (builtin
 * calls are out of line on pip's PoCL, inline_math.h), else the OpenCL builtins. */
#if defined(__clang__)
#define CLSS_CVT8(x, T) __builtin_convertvector((x), T)
#else
#define CLSS_CVT8(x, T) convert_##T(x)
#endif

/* floor of |x| < 2^31 as an int: truncate, then step down where that rounded up (a vector
 * comparison is -1 where true) */
static int8 clss_floori8(float8 x)
{
    const int8 i = CLSS_CVT8(x, int8);
    return i + (CLSS_CVT8(i, float8) > x);
}

static float8 tap_w8(int8 xi, int8 yi, int W, int H, float8 wx, float8 wy)
{
    return ((xi >= 0) & (xi < W) & (yi >= 0) & (yi < H)) ? wx * wy : (float8)(0.0f);
}

static int8 clss_clampi8(int8 v, int lo, int hi)
{
    return v < lo ? (int8)(lo) : (v > hi ? (int8)(hi) : v);
}

#define CLSS_TOF8(x) CLSS_CVT8(x, float8)
WARP_TAPS_FN(warp_taps8, WarpTaps8, float8, int8, clss_floori8, CLSS_TOF8, tap_w8, clss_clampi8)

/* 8 loads of p at the lanes of a long index vector */
#define CLSS_GATHER8(p, i) ((float8)((p)[(i).s0], (p)[(i).s1], (p)[(i).s2], (p)[(i).s3], \
                                     (p)[(i).s4], (p)[(i).s5], (p)[(i).s6], (p)[(i).s7]))

#endif
