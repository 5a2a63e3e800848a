/* GridSample (ONNX opset 16/20, 2-D) and the motion-vector warp built on it.
 *
 * Build options:
 *   -DMODE=0|1|2        nearest | bilinear ("linear") | bicubic ("cubic", Keys a = -0.75)
 *   -DPAD=0|1|2         zeros | border | reflection
 *   -DCLSS_CLANG_VECTORS=0|1  element loads/stores through common.h's FLD/FST
 *                       (clang vector conversions, inline) instead of LD/ST
 *                       (vload_half/vstore_half: out-of-line calls on PoCL, so fp16
 *                       ran several times slower than fp32); 0 is the reference
 *   -DCUBIC_CHANNELS=k  channels [0, k) are sampled bicubic, the rest with MODE: the CLSS
 *                       history (colour 3 + counter, range and logits 13) is warped in one
 *                       pass with its colour bicubic and everything else bilinear.
 *
 * Coordinates follow onnxruntime's CPU kernel (the oracle): a sample position is first
 * mapped to "pixel index" space, where pixel i has its centre at i. Padding is applied to
 * each tap separately (as onnxruntime 1.32, the pinned oracle, and PyTorch do; the ONNX
 * Python reference clamps the position first, which differs for bicubic + border).
 * The grid stays float in every precision: normalised coordinates in half resolve only
 * 2^-11 * W/2 pixels, about one pixel at 4K. Motion offsets are a few pixels and may be
 * T (half resolves 1/64 pixel below 32); all position arithmetic is float. Data is T;
 * nearest copies raw bits (TB).
 *
 * NDRange: (Wo, Ho, N * channel blocks); dimension 0 walks the contiguous output row.
 * One work-item computes the taps and weights of one output pixel once and applies them
 * to a block of `cpb` channels. align_corners is a run-time argument, not a build option:
 * it only moves two constants, and as -D it would double the builds (PoCL compiles each
 * variant again for every work-group size it meets).
 */
#include "common.h"

#define MODE_NEAREST 0
#define MODE_LINEAR 1
#define MODE_CUBIC 2
#define PAD_ZEROS 0
#define PAD_BORDER 1
#define PAD_REFLECTION 2

#ifndef MODE
#define MODE MODE_LINEAR
#endif
#ifndef PAD
#define PAD PAD_ZEROS
#endif
#ifndef CUBIC_CHANNELS
#define CUBIC_CHANNELS 0
#endif

#define NEED_CUBIC (MODE == MODE_CUBIC || CUBIC_CHANNELS > 0)
#define NEED_LINEAR (MODE == MODE_LINEAR)
#define NEED_NEAREST (MODE == MODE_NEAREST)

/* onnxruntime's GsReflect: fold x into [lo, hi] by mirroring at the nearer border.
 * The fold count is kept in float (parity by fmod) so huge coordinates cannot
 * overflow an int; a zero-width range (1 pixel, align_corners) is pixel 0. */
inline float reflect(float x, float lo, float hi)
{
    const float range = hi - lo;
    if (!(range > 0.0f))
        return lo;
    if (x < lo) {
        const float dx = lo - x;
        const float n = floor(dx / range);
        const float r = dx - n * range;
        return fmod(n, 2.0f) == 0.0f ? lo + r : hi - r;
    }
    if (x > hi) {
        const float dx = x - hi;
        const float n = floor(dx / range);
        const float r = dx - n * range;
        return fmod(n, 2.0f) == 0.0f ? hi - r : lo + r;
    }
    return x;
}

/* Resolve one integer-valued tap position on an axis of n pixels to a safe index.
 * *ok is cleared where zeros padding reads 0 (NaN positions included); the index
 * is always in [0, n) so even a NaN or huge coordinate never reads out of bounds. */
inline int tap(float t, int n, int align, int *ok)
{
#if PAD == PAD_ZEROS
    const int in = t >= 0.0f && t < (float)n;
    *ok = in;
    return in ? (int)t : 0;
#else
    *ok = 1;
#if PAD == PAD_REFLECTION
    t = align ? reflect(t, 0.0f, (float)n - 1.0f) : reflect(t, -0.5f, (float)n - 0.5f);
#endif
    /* fmax first: fmax(NaN, 0) = 0 */
    return (int)fmin(fmax(t, 0.0f), (float)(n - 1));
#endif
}

/* Keys cubic convolution weights for taps at -1, 0, 1, 2 around fraction t, in
 * onnxruntime's GsGetCubicCoeffs form. */
inline float4 cubic_weights(float t)
{
    const float a = -0.75f;
    const float x = fabs(t);
    return (float4)(((a * (x + 1.0f) - 5.0f * a) * (x + 1.0f) + 8.0f * a) * (x + 1.0f) - 4.0f * a,
                    ((a + 2.0f) * x - (a + 3.0f)) * x * x + 1.0f,
                    ((a + 2.0f) * (1.0f - x) - (a + 3.0f)) * (1.0f - x) * (1.0f - x) + 1.0f,
                    ((a * (2.0f - x) - 5.0f * a) * (2.0f - x) + 8.0f * a) * (2.0f - x) - 4.0f * a);
}

/* Normalised grid coordinate -> pixel index space, exactly as onnxruntime's
 * GsDenormalize (two roundings, no fma: nearest must pick the same pixel). */
inline float denormalize(float g, int n, int align)
{
#pragma OPENCL FP_CONTRACT OFF
    return align ? (g + 1.0f) / 2.0f * (float)(n - 1) : ((g + 1.0f) * (float)n - 1.0f) / 2.0f;
}

#define VAL(rowp, i, ok) ((ok) ? FLD(rowp, i) : A_ZERO)

/* Sample channels [c0, c1) of image x (one batch item, planes of Hi*Wi) at pixel-index
 * position (xs, ys) and store them to y (already at this output pixel, planes HWo apart). */
inline void sample(__global const T *x, __global T *y, int c0, int c1, long HWo,
                   int Hi, int Wi, int align, float xs, float ys)
{
    const long HWi = (long)Hi * Wi;
    const float flx = floor(xs), fly = floor(ys);
    int c = c0;
#if NEED_CUBIC
    {
        int4 cx, okx, ry, oky;
        int ok;
        cx.s0 = tap(flx - 1.0f, Wi, align, &ok); okx.s0 = ok;
        cx.s1 = tap(flx,        Wi, align, &ok); okx.s1 = ok;
        cx.s2 = tap(flx + 1.0f, Wi, align, &ok); okx.s2 = ok;
        cx.s3 = tap(flx + 2.0f, Wi, align, &ok); okx.s3 = ok;
        ry.s0 = tap(fly - 1.0f, Hi, align, &ok); oky.s0 = ok;
        ry.s1 = tap(fly,        Hi, align, &ok); oky.s1 = ok;
        ry.s2 = tap(fly + 1.0f, Hi, align, &ok); oky.s2 = ok;
        ry.s3 = tap(fly + 2.0f, Hi, align, &ok); oky.s3 = ok;
        ry *= Wi;
        const A4 wx = CONVERT_A4(cubic_weights(xs - flx));
        const A4 wy = CONVERT_A4(cubic_weights(ys - fly));
#if MODE == MODE_CUBIC
        const int cend = c1;
#else
        const int cend = min(c1, CUBIC_CHANNELS);
#endif
        for (; c < cend; ++c) {
            __global const T *p = x + c * HWi;
#define ROW(k) (wx.s0 * VAL(p + ry.s##k, cx.s0, oky.s##k && okx.s0) + \
                wx.s1 * VAL(p + ry.s##k, cx.s1, oky.s##k && okx.s1) + \
                wx.s2 * VAL(p + ry.s##k, cx.s2, oky.s##k && okx.s2) + \
                wx.s3 * VAL(p + ry.s##k, cx.s3, oky.s##k && okx.s3))
            const A v = wy.s0 * ROW(0) + wy.s1 * ROW(1) + wy.s2 * ROW(2) + wy.s3 * ROW(3);
#undef ROW
            FST(y + (c - c0) * HWo, 0, v);
        }
    }
#endif
#if NEED_LINEAR
    if (c < c1) {
        int x1, x2, y1, y2, okx1, okx2, oky1, oky2;
        x1 = tap(flx, Wi, align, &okx1);
        x2 = tap(flx + 1.0f, Wi, align, &okx2);
        y1 = tap(fly, Hi, align, &oky1) * Wi;
        y2 = tap(fly + 1.0f, Hi, align, &oky2) * Wi;
        /* onnxruntime's weights: dx1 = x - x1, dx2 = x2 - x */
        const A dx1 = (A)(xs - flx), dx2 = (A)((flx + 1.0f) - xs);
        const A dy1 = (A)(ys - fly), dy2 = (A)((fly + 1.0f) - ys);
        for (; c < c1; ++c) {
            __global const T *p = x + c * HWi;
            const A v = dy2 * (dx2 * VAL(p + y1, x1, oky1 && okx1) + dx1 * VAL(p + y1, x2, oky1 && okx2)) +
                        dy1 * (dx2 * VAL(p + y2, x1, oky2 && okx1) + dx1 * VAL(p + y2, x2, oky2 && okx2));
            FST(y + (c - c0) * HWo, 0, v);
        }
    }
#endif
#if NEED_NEAREST
    if (c < c1) {
        /* rint rounds half to even, as std::nearbyint in onnxruntime and np.rint in
         * the ONNX reference (PyTorch >= 2.1 agrees). */
        int okx, oky;
        const int xi = tap(rint(xs), Wi, align, &okx);
        const long yi = (long)tap(rint(ys), Hi, align, &oky) * Wi;
        const int ok = okx && oky;
        __global const TB *src = (__global const TB *)x;
        __global TB *dst = (__global TB *)y;
        for (; c < c1; ++c)
            dst[(c - c0) * HWo] = ok ? src[c * HWi + yi + xi] : (TB)0;
    }
#endif
}

/* x: [N, C, Hi, Wi] T; grid: [N, Ho, Wo, 2] float (x then y, normalised to [-1, 1]);
 * y: [N, C, Ho, Wo] T. cpb channels per work-item, nblk = ceil(C / cpb). */
/** @param[in]  x      [N, C, Hi, Wi] input
 *  @param[in]  grid   [N, Ho, Wo, 2] float sample positions (x, y), normalised to [-1, 1]
 *  @param[out] y      [N, C, Ho, Wo] output
 *  @param[in]  C      channels
 *  @param[in]  Hi     input height
 *  @param[in]  Wi     input width
 *  @param[in]  Ho     output height
 *  @param[in]  Wo     output width
 *  @param[in]  cpb    channels per work-item
 *  @param[in]  nblk   ceil(C / cpb)
 *  @param[in]  N      batch
 *  @param[in]  align  ONNX align_corners (0 or 1)
 *  @note -DMODE=0|1|2: nearest | bilinear | bicubic; -DPAD=0|1|2: zeros | border | reflection
 *  @note -DCUBIC_CHANNELS=k: channels [0, k) bicubic; -DCLSS_CLANG_VECTORS=0|1: builtin-free loads
 *  @note -DCLSS_FP16 / -DCLSS_FP16_NATIVE: the storage precision (common.h); T and TB follow it
 */
__kernel void grid_sample(__global const T *x, __global const float *grid, __global T *y,
                          int C, int Hi, int Wi, int Ho, int Wo, int cpb, int nblk, int N, int align)
{
    const int X = get_global_id(0), Y = get_global_id(1), nb = get_global_id(2);
    if (X >= Wo || Y >= Ho || nb >= N * nblk) return;
    const int n = nb / nblk, c0 = (nb % nblk) * cpb, c1 = min(C, c0 + cpb);
    const long HWo = (long)Ho * Wo;
    const float2 g = vload2(0, grid + (((long)n * Ho + Y) * Wo + X) * 2);
    sample(x + (long)n * C * Hi * Wi, y + ((long)n * C + c0) * HWo + (long)Y * Wo + X, c0, c1, HWo,
           Hi, Wi, align, denormalize(g.x, Wi, align), denormalize(g.y, Hi, align));
}

/* The motion-vector form: output pixel (X, Y) of an Ho x Wo grid reads the input at
 *   xs = (X + 0.5) * Wi / Wo - 0.5 + mx * kx,   ys likewise,
 * in pixel-index space (xs = X + mx when sizes agree and kx = 1), where
 * (mx, my) = motion[n, :, Y, X] and (kx, ky) = motion_scale * scale.
 * This is GridSample (align_corners = 0) of the grid
 *   gx = (2X + 1) / Wo - 1 + 2 * mx * kx / Wi,
 * computed here directly in pixels, which keeps full float precision at any size.
 * motion: [N, 2, Ho, Wo] T. */
/** @param[in]  x       [N, C, Hi, Wi] input
 *  @param[in]  motion  [N, 2, Ho, Wo] motion (mx, my)
 *  @param[out] y       [N, C, Ho, Wo] output
 *  @param[in]  C       channels
 *  @param[in]  Hi      input height
 *  @param[in]  Wi      input width
 *  @param[in]  Ho      output height
 *  @param[in]  Wo      output width
 *  @param[in]  cpb     channels per work-item
 *  @param[in]  nblk    ceil(C / cpb)
 *  @param[in]  N       batch
 *  @param[in]  sx      Wi / Wo
 *  @param[in]  sy      Hi / Ho
 *  @param[in]  kx      motion_scale * scale along x (input pixels per motion unit)
 *  @param[in]  ky      likewise along y
 *  @note -DMODE, -DPAD, -DCUBIC_CHANNELS, -DCLSS_CLANG_VECTORS: as grid_sample
 *  @note -DCLSS_FP16 / -DCLSS_FP16_NATIVE: the storage precision (common.h); T and TB follow it
 */
__kernel void warp_motion(__global const T *x, __global const T *motion, __global T *y,
                          int C, int Hi, int Wi, int Ho, int Wo, int cpb, int nblk, int N,
                          float sx, float sy, float kx, float ky)
{
    const int X = get_global_id(0), Y = get_global_id(1), nb = get_global_id(2);
    if (X >= Wo || Y >= Ho || nb >= N * nblk) return;
    const int n = nb / nblk, c0 = (nb % nblk) * cpb, c1 = min(C, c0 + cpb);
    const long HWo = (long)Ho * Wo;
    const long m = (long)n * 2 * HWo + (long)Y * Wo + X;
    const float mx = (float)FLD(motion, m), my = (float)FLD(motion, m + HWo);
    const float xs = ((float)X + 0.5f) * sx - 0.5f + mx * kx;
    const float ys = ((float)Y + 0.5f) * sy - 0.5f + my * ky;
    sample(x + (long)n * C * Hi * Wi, y + ((long)n * C + c0) * HWo + (long)Y * Wo + X, c0, c1, HWo,
           Hi, Wi, 0, xs, ys);
}

/* A float16 grid (an fp16 ONNX model's storage) widened to the float grid the samplers
 * read; vload_half is core OpenCL, so this builds in every precision. */
/** @param[in]  src  [n] half values
 *  @param[out] dst  [n] the same as float
 *  @param[in]  n    elements
 */
__kernel void widen_half(__global const half *src, __global float *dst, int n)
{
    const int i = get_global_id(0);
    if (i < n) dst[i] = vload_half(i, src);
}
