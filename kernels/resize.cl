/* Resize over H and W of an NCHW tensor: ONNX Resize (opsets 10-19) and Upsample.
 *
 * Build options (one source, modes by -D):
 *   -DMODE=0|1|2        nearest | linear (bilinear) | cubic (bicubic)
 *   -DCOORD=0..5        source coordinate of an output index, per axis: 0 half_pixel,
 *                       1 align_corners, 2 asymmetric, 3 pytorch_half_pixel,
 *                       4 tf_crop_and_resize, 5 half_pixel_symmetric (offset from the host)
 *   -DNEAREST_Y, -DNEAREST_X = 0..4   nearest rounding per axis: round_prefer_floor,
 *                       round_prefer_ceil, floor, ceil, and 4 = ceil when the axis
 *                       down-scales else floor (Resize-10/Upsample, as onnxruntime)
 *   -DEXCLUDE=0|1       exclude_outside: taps outside the input get weight 0, renormalised
 *   -DANTIALIAS=0|1     linear/cubic filter stretched by 1/scale when down-scaling
 *   -DCLSS_CLANG_VECTORS=0|1  element loads/stores through common.h's FLD/FST
 *                       (clang vector conversions, inline) instead of LD/ST
 *                       (vload_half/vstore_half: out-of-line calls on PoCL, so fp16
 *                       ran several times slower than fp32); 0 is the reference
 *   -DCPT=n             channels per work-item (default 4): the coordinates and weights
 *                       of a pixel are computed once and reused for n channels
 *
 * Two launches: axis_tables (coordinates, taps and weights per output row and column),
 * then resize, NDRange (output width, output height, N * ceil(C / CPT)); dimension 0
 * walks the contiguous output row. Nearest copies raw bits (TB): bit-exact in every precision.
 *
 * Coordinates follow the ONNX spec and onnxruntime in float32, operation by operation
 * (the ONNX Python reference evaluates the same formulas in float64; a tie that float32
 * rounds onto an integer or a half can pick another nearest pixel than the reference,
 * and the spec's length_resized is the integer output length, see clss/ops/resize.py).
 * Contraction into fma would change those roundings, so it is off for this file.
 */
#include "common.h"

#pragma OPENCL FP_CONTRACT OFF

#ifndef MODE
#define MODE 1
#endif
#ifndef COORD
#define COORD 0
#endif
#ifndef NEAREST_Y
#define NEAREST_Y 0
#endif
#ifndef NEAREST_X
#define NEAREST_X 0
#endif
#ifndef EXCLUDE
#define EXCLUDE 0
#endif
#ifndef ANTIALIAS
#define ANTIALIAS 0
#endif
#ifndef CPT
#define CPT 4
#endif

/* a / b rounded to nearest. OpenCL lets float division be off by 2.5 ulp unless built
 * with -cl-fp32-correctly-rounded-divide-sqrt (PoCL's is), and a coordinate one ulp off
 * can move a nearest-pixel tie. Walk from the device's quotient to the neighbour with the
 * smallest residual |a - q*b|: fma gives the residual exactly for the two floats around
 * a/b, so the walk ends on the correctly rounded quotient. */
static float div_rn(float a, float b)
{
    float q = a / b;
    float r = fabs(fma(-q, b, a));
    for (int k = 0; k < 4; ++k) {
        const float up = nextafter(q, INFINITY), dn = nextafter(q, -INFINITY);
        const float ru = fabs(fma(-up, b, a)), rd = fabs(fma(-dn, b, a));
        if (ru < r && ru <= rd) { q = up; r = ru; }
        else if (rd < r) { q = dn; r = rd; }
        else break;
    }
    return q;
}

/* Output index o -> source coordinate. scale: the given scale (out/in when sizes
 * were given); off: half_pixel_symmetric's offset; r0, r1: the
 * tf_crop_and_resize roi of this axis. */
static float src_coord(int o, float scale, float off, int in, int out, float r0, float r1)
{
    const float y = (float)o;
#if COORD == 0
    return div_rn(y + 0.5f, scale) - 0.5f;
#elif COORD == 5
    /* half_pixel_symmetric: onnxruntime evaluates off + (y + 0.5) / scale - 0.5 in double
     * and rounds once to float. Carry the rounding errors of the quotient and the two
     * sums (exact residual by fma, TwoSum) and round once at the end, which matches that
     * except for values within 2^-53 of a float rounding boundary. */
    const float a = y + 0.5f, q = div_rn(a, scale), ql = fma(-q, scale, a) / scale;
    const float t = off + q, tb = t - off, te = (off - (t - tb)) + (q - tb);
    const float u = t - 0.5f, ub = u - t, ue = (t - (u - ub)) + (-0.5f - ub);
    return u + (ue + (te + ql));
#elif COORD == 1
    return out == 1 ? 0.0f : div_rn(y * (float)(in - 1), (float)(out - 1));
#elif COORD == 2
    return div_rn(y, scale);
#elif COORD == 3
    return out > 1 ? div_rn(y + 0.5f, scale) - 0.5f : 0.0f;
#else
    return out > 1 ? r0 * (float)(in - 1) + div_rn(y * (r1 - r0) * (float)(in - 1), (float)(out - 1))
                   : 0.5f * (r0 + r1) * (float)(in - 1);
#endif
}

/* Nearest index of coordinate x. A fraction within 1e-6 of one half counts as a tie,
 * as in onnxruntime's CPU kernel (>= 1.2x): it undoes float32 rounding of coordinates
 * that are exact halves (3.5 computed as 3.4999998), which float64 (the ONNX reference)
 * keeps exact. x - floor(x) and r - 0.5f are exact in float32. */
static int nearest_index(float x, int in, int rule, float scale)
{
    const float f = floor(x);
    int i = (int)f;
    if (x != f) {
        const float r = x - f;
        const int tie = fabs(r - 0.5f) <= 1e-6f;
        if (rule == 0)
            i += tie ? 0 : r > 0.5f;
        else if (rule == 1)
            i += tie ? 1 : r > 0.5f;
        else if (rule == 3 || (rule == 4 && scale < 1.0f))
            i += 1;
    }
    return clamp(i, 0, in - 1);
}

/* Keys cubic convolution weights of the 4 taps floor(x)-1 .. floor(x)+2 at t = x - floor(x),
 * written as the ONNX reference writes them. */
static float4 cubic_weights(float t, float a)
{
    const float t1 = t + 1.0f, u = 1.0f - t, u1 = u + 1.0f;
    return (float4)(((a * t1 - 5.0f * a) * t1 + 8.0f * a) * t1 - 4.0f * a,
                    ((a + 2.0f) * t - (a + 3.0f)) * t * t + 1.0f,
                    ((a + 2.0f) * u - (a + 3.0f)) * u * u + 1.0f,
                    ((a * u1 - 5.0f * a) * u1 + 8.0f * a) * u1 - 4.0f * a);
}

/* The antialias filters at distance d (in filter units). */
static float aa_filter(float d, float a)
{
    d = fabs(d);
#if MODE == 1
    return clamp(1.0f - d, 0.0f, 1.0f);
#else
    const float d2 = d * d, d3 = d2 * d;
    if (d <= 1.0f) return (a + 2.0f) * d3 - (a + 3.0f) * d2 + 1.0f;
    if (d < 2.0f) return a * d3 - 5.0f * a * d2 + 8.0f * a * d - 4.0f * a;
    return 0.0f;
#endif
}

/* Fixed-tap weights and clamped (edge-padded) indices of one axis. */
#if MODE == 1
#define TAPS 2
#else
#define TAPS 4
#endif

static void axis_taps(float x, int in, float a, float *w, int *idx)
{
    const float f = floor(x), t = x - f;
    const int i0 = (int)f - (TAPS == 4);
#if MODE == 1
    w[0] = 1.0f - t;
    w[1] = t;
#else
    const float4 c = cubic_weights(t, a);
    w[0] = c.s0; w[1] = c.s1; w[2] = c.s2; w[3] = c.s3;
#endif
#if EXCLUDE
    float sum = 0.0f;
    for (int k = 0; k < TAPS; ++k) {
        if (i0 + k < 0 || i0 + k >= in) w[k] = 0.0f;
        sum += w[k];
    }
    for (int k = 0; k < TAPS; ++k) w[k] /= sum;
#endif
    for (int k = 0; k < TAPS; ++k) idx[k] = clamp(i0 + k, 0, in - 1);
}

/* Everything that depends on one axis only, once per output row and column instead of
 * once per output element and channel block (the correctly rounded division alone is a
 * loop of library calls on some compilers). One work-item per output index: o < Ho is
 * row o, else column o - Ho. tab layout, n = Ho + Wo:
 *   coord[n] float   the source coordinate
 *   idx[n * TAPS]    int tap indices, edge-clamped (nearest: idx[o] is the pixel)
 *   wt[n * TAPS]     float tap weights (linear/cubic without antialias) */
/** @param[in]  Ho      output height (work-items [0, Ho) are rows)
 *  @param[in]  Wo      output width (work-items [Ho, Ho + Wo) are columns)
 *  @param[in]  H       input height
 *  @param[in]  W       input width
 *  @param[in]  sy      scale along y (output / input)
 *  @param[in]  sx      scale along x
 *  @param[in]  oy      coordinate offset along y (half_pixel_symmetric), from the host
 *  @param[in]  ox      coordinate offset along x
 *  @param[in]  roi     tf_crop_and_resize region (y0, x0, y1, x1), normalised
 *  @param[in]  cubic_a the cubic coefficient (ONNX cubic_coeff_a)
 *  @param[out] coord   [Ho + Wo] source coordinate of each output row and column
 *  @param[out] idx     [(Ho + Wo) * TAPS] edge-clamped tap indices
 *  @param[out] wt      [(Ho + Wo) * TAPS] tap weights
 *  @note -DMODE, -DCOORD, -DNEAREST_Y, -DNEAREST_X, -DEXCLUDE, -DANTIALIAS: as for resize (top of this file)
 */
__kernel void axis_tables(int Ho, int Wo, int H, int W, float sy, float sx, float oy, float ox,
                          float4 roi, float cubic_a, __global float *coord, __global int *idx,
                          __global float *wt)
{
    const int o = get_global_id(0);
    if (o >= Ho + Wo) return;
    const int is_x = o >= Ho, i = is_x ? o - Ho : o;
    const int in = is_x ? W : H;
    const float s = is_x ? sx : sy;
    const float f = is_x ? src_coord(i, sx, ox, W, Wo, roi.s1, roi.s3)
                         : src_coord(i, sy, oy, H, Ho, roi.s0, roi.s2);
    coord[o] = f;
#if MODE == 0
    idx[o] = nearest_index(f, in, is_x ? NEAREST_X : NEAREST_Y, s);
#elif !ANTIALIAS
    float w[TAPS];
    int t[TAPS];
    axis_taps(f, in, cubic_a, w, t);
    for (int k = 0; k < TAPS; ++k) {
        idx[o * TAPS + k] = t[k];
        wt[o * TAPS + k] = w[k];
    }
#endif
}

/* tab: axis_tables' output for this resize (rows at 0, columns at Ho). */
/** @param[in]  in      [N, C, H, W] input
 *  @param[out] out     [N, C, Ho, Wo] output
 *  @param[in]  C       channels
 *  @param[in]  H       input height
 *  @param[in]  W       input width
 *  @param[in]  Ho      output height
 *  @param[in]  Wo      output width
 *  @param[in]  NCb     N * ceil(C / CPT), the extent of NDRange dimension 2
 *  @param[in]  sy      scale along y (output / input)
 *  @param[in]  sx      scale along x
 *  @param[in]  extrap  tf_crop_and_resize extrapolation value (outside the input)
 *  @param[in]  cubic_a the cubic coefficient (ONNX cubic_coeff_a)
 *  @param[in]  coord   axis_tables' source coordinates
 *  @param[in]  idx     axis_tables' tap indices
 *  @param[in]  wt      axis_tables' tap weights
 *  @note -DMODE=0|1|2, -DCOORD=0..5, -DNEAREST_Y/-DNEAREST_X, -DEXCLUDE, -DANTIALIAS: the ONNX attributes (top of this file)
 *  @note -DCPT=n: channels per work-item; -DCLSS_CLANG_VECTORS=0|1: builtin-free loads
 *  @note -DCLSS_FP16 / -DCLSS_FP16_NATIVE: the storage precision (common.h); T and TB follow it
 */
__kernel void resize(__global const T *in, __global T *out,
                     int C, int H, int W, int Ho, int Wo, int NCb,
                     float sy, float sx, float extrap, float cubic_a,
                     __global const float *coord, __global const int *idx, __global const float *wt)
{
    const int X = get_global_id(0), Y = get_global_id(1), ncb = get_global_id(2);
    if (X >= Wo || Y >= Ho || ncb >= NCb) return;
    const int CB = (C + CPT - 1) / CPT;
    const int n = ncb / CB, c0 = (ncb % CB) * CPT;
    const int nc = min(CPT, C - c0);
    const long plane = (long)H * W, oplane = (long)Ho * Wo;
    __global const T *src = in + ((long)n * C + c0) * plane;
    const long o = ((long)n * C + c0) * oplane + (long)Y * Wo + X;
    const int ox_ = Ho + X;

#if COORD == 4 || ANTIALIAS
    const float fy = coord[Y], fx = coord[ox_];
#endif
#if COORD == 4
    /* tf_crop_and_resize: a source outside the input is the extrapolation value. */
    if (fy < 0.0f || fy > (float)(H - 1) || fx < 0.0f || fx > (float)(W - 1)) {
        for (int c = 0; c < nc; ++c) FST(out, o + c * oplane, extrap);
        return;
    }
#endif

#if MODE == 0
    const long s = (long)idx[Y] * W + idx[ox_];
    __global const TB *sb = (__global const TB *)src;
    __global TB *ob = (__global TB *)out;
    for (int c = 0; c < nc; ++c) ob[o + c * oplane] = sb[c * plane + s];

#elif ANTIALIAS
    /* The filter stretched by 1/scale when down-scaling covers |j - x| < support/scale'
     * taps, j in [floor(x) + 1 - k, floor(x) + k] with k = ceil(support/scale'); taps
     * beyond the edges repeat the edge pixel unless excluded. */
    const float support = MODE == 1 ? 1.0f : 2.0f;
    const float ay = fmin(sy, 1.0f), ax = fmin(sx, 1.0f);
    const int ky = (int)ceil(support / ay), kx = (int)ceil(support / ax);
    const int y0 = (int)floor(fy) + 1 - ky, x0 = (int)floor(fx) + 1 - kx;
    float sumy = 0.0f, sumx = 0.0f;
    for (int j = y0; j < y0 + 2 * ky; ++j)
        if (!EXCLUDE || (j >= 0 && j < H)) sumy += aa_filter(((float)j - fy) * ay, cubic_a);
    for (int i = x0; i < x0 + 2 * kx; ++i)
        if (!EXCLUDE || (i >= 0 && i < W)) sumx += aa_filter(((float)i - fx) * ax, cubic_a);
    const float norm = 1.0f / (sumy * sumx);
    A acc[CPT];
    for (int c = 0; c < CPT; ++c) acc[c] = A_ZERO;
    for (int j = y0; j < y0 + 2 * ky; ++j) {
        if (EXCLUDE && (j < 0 || j >= H)) continue;
        const float wy = aa_filter(((float)j - fy) * ay, cubic_a) * norm;
        __global const T *row = src + (long)clamp(j, 0, H - 1) * W;
        for (int i = x0; i < x0 + 2 * kx; ++i) {
            if (EXCLUDE && (i < 0 || i >= W)) continue;
            const A w = CONVERT_A(wy * aa_filter(((float)i - fx) * ax, cubic_a));
            const int xi = clamp(i, 0, W - 1);
#pragma unroll
            for (int c = 0; c < CPT; ++c)
                if (c < nc) acc[c] += w * FLD(row, c * plane + xi);
        }
    }
    for (int c = 0; c < nc; ++c) FST(out, o + c * oplane, acc[c]);

#else
    A wy[TAPS], wx[TAPS];
    int iy[TAPS], ix[TAPS];
#pragma unroll
    for (int k = 0; k < TAPS; ++k) {
        wy[k] = CONVERT_A(wt[Y * TAPS + k]);
        wx[k] = CONVERT_A(wt[ox_ * TAPS + k]);
        iy[k] = idx[Y * TAPS + k];
        ix[k] = idx[ox_ * TAPS + k];
    }
    for (int c = 0; c < nc; ++c) {
        __global const T *p = src + c * plane;
        A acc = A_ZERO;
#pragma unroll
        for (int r = 0; r < TAPS; ++r) {
            __global const T *row = p + (long)iy[r] * W;
            A racc = A_ZERO;
#pragma unroll
            for (int k = 0; k < TAPS; ++k) racc += wx[k] * FLD(row, ix[k]);
            acc += wy[r] * racc;
        }
        FST(out, o + c * oplane, acc);
    }
#endif
}

/* Linear and cubic resize (no antialias, not tf_crop_and_resize) with 8
 * consecutive outputs along x per work-item: the host's fast path (RESIZE_X8=1
 * in clss/ops/resize.py; `resize` above is its reference and computes each
 * output with the same operations in the same order). The row taps and weights
 * are read once per work-item instead of once per output, and a full block of
 * outputs is one 8-wide store per channel. Same arguments as `resize`;
 * NDRange (ceil(Wo / 8), Ho, N * ceil(C / CPT)). Nearest (MODE 0; the host's fast path
 * resize.nearest_x8) copies the 8 input pixels axis_tables chose as one vector of raw
 * bits (bit-exact). */
#if !ANTIALIAS && COORD != 4
/** @param[in]  in      [N, C, H, W] input
 *  @param[out] out     [N, C, Ho, Wo] output
 *  @param[in]  C       channels
 *  @param[in]  H       input height
 *  @param[in]  W       input width
 *  @param[in]  Ho      output height
 *  @param[in]  Wo      output width
 *  @param[in]  NCb     N * ceil(C / CPT), the extent of NDRange dimension 2
 *  @param[in]  sy      scale along y (output / input)
 *  @param[in]  sx      scale along x
 *  @param[in]  extrap  tf_crop_and_resize extrapolation value (outside the input)
 *  @param[in]  cubic_a the cubic coefficient (ONNX cubic_coeff_a)
 *  @param[in]  coord   axis_tables' source coordinates
 *  @param[in]  idx     axis_tables' tap indices
 *  @param[in]  wt      axis_tables' tap weights
 *  @note -DMODE=0|1|2, -DCOORD=0..5, -DNEAREST_Y/-DNEAREST_X, -DEXCLUDE, -DANTIALIAS: the ONNX attributes (top of this file)
 *  @note -DCPT=n: channels per work-item; -DCLSS_CLANG_VECTORS=0|1: builtin-free loads
 *  @note -DCLSS_FP16 / -DCLSS_FP16_NATIVE: the storage precision (common.h); T and TB follow it
 */
__kernel void resize_x8(__global const T *in, __global T *out,
                        int C, int H, int W, int Ho, int Wo, int NCb,
                        float sy, float sx, float extrap, float cubic_a,
                        __global const float *coord, __global const int *idx, __global const float *wt)
{
    const int X0 = get_global_id(0) * 8, Y = get_global_id(1), ncb = get_global_id(2);
    if (X0 >= Wo || Y >= Ho || ncb >= NCb) return;
    const int CB = (C + CPT - 1) / CPT;
    const int n = ncb / CB, c0 = (ncb % CB) * CPT;
    const int nc = min(CPT, C - c0);
    const int nx = min(8, Wo - X0);
    const long plane = (long)H * W, oplane = (long)Ho * Wo;
    __global const T *src = in + ((long)n * C + c0) * plane;
    const long o = ((long)n * C + c0) * oplane + (long)Y * Wo + X0;
#if MODE == 0
    __global const TB *sb = (__global const TB *)src + (long)idx[Y] * W;
    __global TB *ob = (__global TB *)out + o;
    int ix[8];
    for (int e = 0; e < 8; ++e)
        ix[e] = idx[Ho + X0 + min(e, nx - 1)];
    for (int c = 0; c < nc; ++c) {
        __global const TB *r = sb + c * plane;
        if (nx == 8) {
            TB_ST8(ob + c * oplane,
                   (TB8)(r[ix[0]], r[ix[1]], r[ix[2]], r[ix[3]], r[ix[4]], r[ix[5]], r[ix[6]], r[ix[7]]));
        } else {
            for (int e = 0; e < nx; ++e)
                ob[c * oplane + e] = r[ix[e]];
        }
    }
#else
    A wy[TAPS], wx[8][TAPS];
    int iy[TAPS], ix[8][TAPS];
#pragma unroll
    for (int k = 0; k < TAPS; ++k) {
        wy[k] = CONVERT_A(wt[Y * TAPS + k]);
        iy[k] = idx[Y * TAPS + k];
    }
#pragma unroll
    for (int e = 0; e < 8; ++e) {
        const int ox_ = Ho + X0 + min(e, nx - 1);     /* the tail repeats its last column */
#pragma unroll
        for (int k = 0; k < TAPS; ++k) {
            wx[e][k] = CONVERT_A(wt[ox_ * TAPS + k]);
            ix[e][k] = idx[ox_ * TAPS + k];
        }
    }
    for (int c = 0; c < nc; ++c) {
        __global const T *p = src + c * plane;
        union { A8 v; A e[8]; } acc;
        acc.v = (A8)A_ZERO;
#pragma unroll
        for (int r = 0; r < TAPS; ++r) {
            __global const T *row = p + (long)iy[r] * W;
#pragma unroll
            for (int e = 0; e < 8; ++e) {
                A racc = A_ZERO;
#pragma unroll
                for (int k = 0; k < TAPS; ++k) racc += wx[e][k] * FLD(row, ix[e][k]);
                acc.e[e] += wy[r] * racc;
            }
        }
        if (nx == 8) {
            FST8(out, o + c * oplane, acc.v);
        } else {
            for (int e = 0; e < nx; ++e)
                FST(out, o + c * oplane + e, acc.e[e]);
        }
    }
#endif
}
#endif

/* Nearest resize on the channel-blocked layout [N][Cb][H][W][BLK] (clss/model/layout.py):
 * a work-item copies one output pixel's block of BLK channels (-DBLK=8|16) from the input
 * pixel axis_tables chose, as one vector of raw bits (bit-exact, as resize_x8's MODE 0).
 * Any nearest geometry but tf_crop_and_resize (COORD 4). A block is BLK-aligned.
 * @param[in]  in    [NCb, H, W, BLK] input
 * @param[out] out   [NCb, Ho, Wo, BLK] output
 * @param[in]  H     input height
 * @param[in]  W     input width
 * @param[in]  Ho    output height
 * @param[in]  Wo    output width
 * @param[in]  NCb   N * Cb, the extent of NDRange dimension 2
 * @param[in]  idx   axis_tables' tap indices (rows, then columns)
 * @note NDRange (Wo, Ho, NCb); -DBLK=8|16 */
#ifndef BLK
#define BLK 16
#endif
#if BLK == 16
typedef TB16 TBB;
#elif BLK == 8
typedef TB8 TBB;
#else
#error "BLK must be 8 or 16"
#endif
__kernel void resize_nearest_blocked(__global const TBB *in, __global TBB *out, int H, int W, int Ho,
                                     int Wo, int NCb, __global const int *idx)
{
    const int X = get_global_id(0), Y = get_global_id(1), z = get_global_id(2);
    if (X >= Wo || Y >= Ho || z >= NCb) return;
    out[((long)z * Ho + Y) * Wo + X] = in[((long)z * H + idx[Y]) * W + idx[Ho + X]];
}
