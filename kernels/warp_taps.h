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

static WarpTaps warp_taps(float xs, float ys, int W, int H)
{
    WarpTaps t;
    const int x0 = clss_floori(xs), y0 = clss_floori(ys);
    const float ax = xs - (float)x0, ay = ys - (float)y0;
    t.w00 = tap_w(x0, y0, W, H, 1.0f - ax, 1.0f - ay);
    t.w10 = tap_w(x0 + 1, y0, W, H, ax, 1.0f - ay);
    t.w01 = tap_w(x0, y0 + 1, W, H, 1.0f - ax, ay);
    t.w11 = tap_w(x0 + 1, y0 + 1, W, H, ax, ay);
    t.cx0 = clss_clampi(x0, 0, W - 1);
    t.cx1 = clss_clampi(x0 + 1, 0, W - 1);
    t.cy0 = clss_clampi(y0, 0, H - 1);
    t.cy1 = clss_clampi(y0 + 1, 0, H - 1);
    return t;
}

#endif
