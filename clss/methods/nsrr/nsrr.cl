/* NSRR's frame step around its networks (Xiao et al. 2020, section 3.2; the room
 * clss/methods/nsrr/, its ONNX twin oracle.py states the same formulas as graph nodes).
 *
 *   nsrr_prepare    caller's colour / depth / motion (image layout, float32) -> rgbd
 *                   [4,h,w] (PQ colour, reversed-Z depth; storage T) and motion [2,h,w]
 *                   (render pixels, float32)
 *   nsrr_reproject  the current features [12,h,w] zero-upsampled to [12,Hp,Wp] with the
 *                   frame's jitter, the render motion upsampled bilinearly to output
 *                   pixels, and the history (the previous frames' zero-upsampled features,
 *                   each already warped to the previous frame) warped one step more:
 *                   stack = [Z_i, warp(hist slot 0..N-1)], the reconstruction's input
 *   nsrr_finish     network output [3,Hp,Wp] (PQ) -> the caller's image, linear
 *
 * Accumulative warping: the history holds, for k = 1..N, frame i-k's zero-upsampled
 * features warped through the motions of frames i-k+1 .. i-1 (channels 12(k-1)..12k-1).
 * One bilinear warp by frame i's motion brings every slot to frame i; stack[0:12N] is
 * then the next frame's history, copied by the host's queue after the network. Frame
 * i-k has been warped k times, the paper's iterative warping.
 *
 * Padding: the output is computed on Hp x Wp (multiples of 4, for the U-Net's two
 * poolings); every channel is 0 outside H x W, and the warp reads only inside H x W
 * (zero padding, per tap, as ONNX GridSample padding_mode="zeros").
 */
#include "common.h"

#pragma OPENCL FP_CONTRACT OFF

#define FEAT 12

#include "zero_upsample.h"

#include "pq.h"
#include "warp_taps.h"

/** @param[in]  color          [h,w,3] float32 linear
 *  @param[in]  depth          [h,w] float32 in [0, 1]
 *  @param[in]  motion         [h,w,2] float32, the caller's units
 *  @param[out] rgbd           [4,h,w] T: PQ colour (of colour / exposure), reversed-Z depth
 *  @param[out] mv             [2,h,w] float32 render pixels (motion * motion_scale)
 *  @param[in]  w              render width
 *  @param[in]  h              render height
 *  @param[in]  depth_inverted 1: depth is reversed-Z already, 0: 1 - depth
 *  @param[in]  msx            motion scale x
 *  @param[in]  msy            motion scale y
 *  @param[in]  inv_exposure   1 / exposure
 *  @param[in]  pq_scale       nits / 10000
 *  @param[out] dep            [h,w] float32 reversed-Z depth (the depth rejection's, kept
 *                             in float32 in every precision so that its decisions match)
 *  Non-finite values become 0 colour, far depth and 0 motion (the host path refuses
 *  them before, unless the caller asked to sanitize).
 *  NDRange: (w, h). */
__kernel void nsrr_prepare(__global const float *color, __global const float *depth,
                           __global const float *motion, __global T *rgbd, __global float *mv,
                           int w, int h, int depth_inverted, float msx, float msy,
                           float inv_exposure, float pq_scale, __global float *dep)
{
    const int x = get_global_id(0), y = get_global_id(1);
    if (x >= w || y >= h) return;
    const int p = y * w + x, plane = w * h;
    for (int c = 0; c < 3; ++c) {
        float v = color[3 * p + c];
        v = isfinite(v) ? v * inv_exposure : 0.0f;
        ST(rgbd, c * plane + p, pq_encode(v, pq_scale));
    }
    float d = depth[p];
    d = isfinite(d) ? (depth_inverted ? d : 1.0f - d) : 0.0f;
    ST(rgbd, 3 * plane + p, d);
    dep[p] = d;
    const float mx = motion[2 * p], my = motion[2 * p + 1];
    mv[p] = isfinite(mx) ? mx * msx : 0.0f;
    mv[plane + p] = isfinite(my) ? my * msy : 0.0f;
}


/* The two samples either side of index coordinate u on an axis of n samples, u clamped
 * to [0, n - 1] (edge-clamped), and u's fraction between them: every edge-clamped bilinear
 * read of this file (render_motion, the base, depth_keep). */
typedef struct { int i0, i1; float f; } AxisTaps;
static AxisTaps axis_taps(float u, int n)
{
    AxisTaps a;
    u = clss_clampf(u, 0.0f, (float)(n - 1));
    a.i0 = clss_floori(u);
    a.i1 = clss_mini(a.i0 + 1, n - 1);
    a.f = u - (float)a.i0;
    return a;
}

/* The render motion at output pixel (X, Y): bilinear, half-pixel centres, clamped to the
 * edge (ONNX Resize linear, half_pixel), in render pixels. */
static float2 render_motion(__global const float *mv, int h, int w, int X, int Y, float sy,
                            float sx)
{
    const long plane = (long)h * w;
    const AxisTaps a = axis_taps(((float)X + 0.5f) / sx - 0.5f, w);
    const AxisTaps b = axis_taps(((float)Y + 0.5f) / sy - 0.5f, h);
    const int u0 = a.i0, u1 = a.i1, v0 = b.i0, v1 = b.i1;
    const float fu = a.f, fv = b.f;
    float m[2];
    for (int c = 0; c < 2; ++c) {
        __global const float *q = mv + c * plane;
        const float top = q[v0 * w + u0] * (1.0f - fu) + q[v0 * w + u1] * fu;
        const float bot = q[v1 * w + u0] * (1.0f - fu) + q[v1 * w + u1] * fu;
        m[c] = top * (1.0f - fv) + bot * fv;
    }
    return (float2)(m[0], m[1]);
}

/* The depth rejection (networks.REJECTS, "depth"): 1 keeps the warped history at output
 * pixel (X, Y), which was at (xs, ys) in the previous frame; 0 empties it. The current
 * depth range is the 2x2 render samples around the pixel centre (jitter-aware, as the
 * base), the previous one the 2x2 of the previous frame around (xs + 0.5) / sx - 0.5
 * (clamped); a disocclusion is where the two lie apart by more than tau x the larger
 * (reversed-Z: the nearer). The twins compute the same (oracle.py, twin.py depth_keep). */
#define DMIN(a, b) ((a) < (b) ? (a) : (b))  /* fmin / fmax of finite values, inline */
#define DMAX(a, b) ((a) > (b) ? (a) : (b))
static int depth_keep(__global const float *dcur, __global const float *dprev, int h, int w,
                      int X, int Y, float xs, float ys, float sy, float sx, float jy, float jx,
                      float tau)
{
    const AxisTaps b = axis_taps(((float)X + 0.5f) / sx - 0.5f - jx, w);
    const AxisTaps c = axis_taps(((float)Y + 0.5f) / sy - 0.5f - jy, h);
    const float t0 = dcur[c.i0 * w + b.i0], t1 = dcur[c.i0 * w + b.i1];
    const float t2 = dcur[c.i1 * w + b.i0], t3 = dcur[c.i1 * w + b.i1];
    const float cmin = DMIN(DMIN(t0, t1), DMIN(t2, t3)), cmax = DMAX(DMAX(t0, t1), DMAX(t2, t3));
    const AxisTaps u = axis_taps((xs + 0.5f) / sx - 0.5f, w);
    const AxisTaps v = axis_taps((ys + 0.5f) / sy - 0.5f, h);
    const float p0 = dprev[v.i0 * w + u.i0], p1 = dprev[v.i0 * w + u.i1];
    const float p2 = dprev[v.i1 * w + u.i0], p3 = dprev[v.i1 * w + u.i1];
    const float pmin = DMIN(DMIN(p0, p1), DMIN(p2, p3)), pmax = DMAX(DMAX(p0, p1), DMAX(p2, p3));
    return DMAX(cmin, pmin) - DMIN(cmax, pmax) <= DMAX(cmax, pmax) * tau;
}

/** @param[in]  feat     [12,h,w] T: the current frame's features
 *  @param[in]  mv       [2,h,w] float32 render-pixel motion (previous = p + mv)
 *  @param[in]  hist     [12*N,Hp,Wp] T: the history (see the file comment)
 *  @param[out] stack    [12*(N+1),Hp,Wp] T: [Z_i, the history warped to frame i]
 *  @param[out] base     [3,Hp,Wp] T: the current PQ colour (feat channels 0-2) bilinear at
 *                       the output pixel centres, jitter-aware, edge-clamped (the residual
 *                       base; 0 in the padding)
 *  @param[in]  h        render height
 *  @param[in]  w        render width
 *  @param[in]  H        output height
 *  @param[in]  W        output width
 *  @param[in]  Hp       padded output height (multiple of 4)
 *  @param[in]  Wp       padded output width
 *  @param[in]  nprev    N, the history slots
 *  @param[in]  nvalid   slots in use (<= N; slots >= nvalid are written 0)
 *  @param[in]  siy      integer scale along y, 0 for a fractional one (sy is used)
 *  @param[in]  six      integer scale along x, 0 for a fractional one
 *  @param[in]  oy       integer-scale sample offset in the block, from the host
 *  @param[in]  ox       integer-scale sample offset along x
 *  @param[in]  sy       H / h
 *  @param[in]  sx       W / w
 *  @param[in]  jy       jitter y, render pixels
 *  @param[in]  jx       jitter x, render pixels
 *  @param[in]  mode     0: warp the history; 1: reset, empty history (zeros); 2: reset,
 *                       every valid slot is the current frame's Z (duplicate)
 *  @param[in]  dcur     [h,w] float32 the current reversed-Z depth (nsrr_prepare's dep)
 *  @param[in]  dprev    [h,w] float32 the previous frame's
 *  @param[in]  tau      the depth rejection's threshold (depth_keep), < 0: off
 *  NDRange: (Wp, Hp). */
#ifndef VEC
#define VEC 1       /* 8: nsrr_reproject takes runs of 8 output pixels of a row (the CPU fast path) */
#endif
#ifndef RUNS
#define RUNS 1      /* with VEC 8: runs of 8 pixels per work-item */
#endif

#if VEC == 1
__kernel void nsrr_reproject(__global const T *feat, __global const float *mv,
                             __global const T *hist, __global T *stack, __global T *base,
                             int h, int w, int H, int W, int Hp, int Wp, int nprev, int nvalid,
                             int siy, int six, int oy, int ox, float sy, float sx,
                             float jy, float jx, int mode, __global const float *dcur,
                             __global const float *dprev, float tau)
{
    const int X = get_global_id(0), Y = get_global_id(1);
    if (X >= Wp || Y >= Hp) return;
    const long oplane = (long)Hp * Wp, o = (long)Y * Wp + X;
    const int nch = FEAT * (nprev + 1);
    if (X >= W || Y >= H) {
        for (int c = 0; c < nch; ++c) ST(stack, c * oplane + o, 0.0f);
        for (int c = 0; c < 3; ++c) ST(base, c * oplane + o, 0.0f);
        return;
    }
    {
        /* render sample j was taken at j + 0.5 + jitter: this pixel's centre at index bu */
        const AxisTaps bu = axis_taps(((float)X + 0.5f) / sx - 0.5f - jx, w);
        const AxisTaps bv = axis_taps(((float)Y + 0.5f) / sy - 0.5f - jy, h);
        const int b0 = bu.i0, b1 = bu.i1, c0 = bv.i0, c1 = bv.i1;
        const float fb = bu.f, fc = bv.f;
        const long pl = (long)h * w;
        for (int c = 0; c < 3; ++c) {
            __global const T *q = feat + c * pl;
            const float top = LD(q, (long)c0 * w + b0) * (1.0f - fb) + LD(q, (long)c0 * w + b1) * fb;
            const float bot = LD(q, (long)c1 * w + b0) * (1.0f - fb) + LD(q, (long)c1 * w + b1) * fb;
            ST(base, c * oplane + o, top * (1.0f - fc) + bot * fc);
        }
    }
    /* Z_i: the sample whose jittered position lies in this output pixel, else 0. */
    const int i = zu_source(Y, h, siy, oy, sy, jy);
    const int j = i < 0 ? -1 : zu_source(X, w, six, ox, sx, jx);
    const long plane = (long)h * w;
    float z[FEAT];
    for (int c = 0; c < FEAT; ++c) {
        z[c] = j < 0 ? 0.0f : LD(feat, c * plane + (long)i * w + j);
        ST(stack, c * oplane + o, z[c]);
    }
    if (mode != 0) {
        for (int k = 0; k < nprev; ++k)
            for (int c = 0; c < FEAT; ++c)
                ST(stack, (FEAT * (k + 1) + c) * oplane + o, (mode == 2 && k < nvalid) ? z[c] : 0.0f);
        return;
    }
    /* Backward warp: this pixel was at (X + mx, Y + my) in the previous frame. */
    const float2 m = render_motion(mv, h, w, X, Y, sy, sx);
    const float xs = (float)X + m.x * sx, ys = (float)Y + m.y * sy;
    const WarpTaps t = warp_taps(xs, ys, W, H);
    const float w00 = t.w00, w10 = t.w10, w01 = t.w01, w11 = t.w11;
    const int cx0 = t.cx0, cx1 = t.cx1, cy0 = t.cy0, cy1 = t.cy1;
    const long a00 = (long)cy0 * Wp + cx0, a10 = (long)cy0 * Wp + cx1;
    const long a01 = (long)cy1 * Wp + cx0, a11 = (long)cy1 * Wp + cx1;
    const bool kept = tau < 0.0f || depth_keep(dcur, dprev, h, w, X, Y, xs, ys, sy, sx, jy, jx, tau);
    for (int k = 0; k < nprev; ++k) {
        const bool on = k < nvalid && kept;
        for (int c = 0; c < FEAT; ++c) {
            float r = 0.0f;
            if (on) {
                __global const T *p = hist + (long)(FEAT * k + c) * oplane;
                r = LD(p, a00) * w00 + LD(p, a10) * w10 + LD(p, a01) * w01 + LD(p, a11) * w11;
            }
            ST(stack, (FEAT * (k + 1) + c) * oplane + o, r);
        }
    }
}
#else
/* The same per pixel, on runs of 8 output pixels of a row (the CPU fast path), and
 * split by planes: work-item (x, Y, g) writes RUNS runs of the planes of group g, where
 * group 0 is the base and Z_i (15 planes) and group g >= 1 the G history channels from
 * 12 + (g - 1) * G. One work-item writing all 63 planes kept 63 store streams and 96
 * gather rows open at once, which defeats the hardware prefetchers: 545 ms at 1080p,
 * where a plane group of G = 4 runs in a fraction of that. The warp's sample
 * positions come from nsrr_warp_coords, computed once per pixel, not once per group.
 * Every lane runs the reference's operations on the same values (warp_taps8 is
 * warp_taps lane by lane), so the outputs equal VEC 1's. NDRange:
 * (ceil(Wp / (8 * RUNS)), Hp, 1 + 12 * N / G). */
#ifndef G
#define G 4         /* history channels per plane group (divides 12) */
#endif

/* all(m) of an int8 comparison, as plain vector ANDs (every lane -1) */
static inline int all8(int8 m)
{
    const int4 a = m.lo & m.hi;
    const int2 b = a.lo & a.hi;
    return (b.x & b.y) < 0;
}

/* Store the first n (<= 8) lanes of v at element offset i of p. */
#if defined(CLSS_FP16) && !(CLSS_CLANG_VECTORS && defined(__clang__))
/* lane by lane: pip's PoCL 3.0 crashed on vstore_half8_rte here (it takes the clang form) */
#define PUT8_FULL(p, i, v) do { float t_[8]; PST8(t_, (v));      \
        for (int q_ = 0; q_ < 8; ++q_) ST(p, (i) + q_, t_[q_]); } while (0)
#else
#define PUT8_FULL(p, i, v) FST8(p, i, CLSS_CVT8((v), A8))
#endif
#define PUT8(p, i, v, n) do {                                       \
        if ((n) == 8) { PUT8_FULL(p, i, v); }                        \
        else { float t_[8]; PST8(t_, (v));                           \
               for (int q_ = 0; q_ < (n); ++q_) FST(p, (i) + q_, t_[q_]); } \
    } while (0)

/** The warp's sample position of every output pixel: (X + m.x * sx, Y + m.y * sy), m
 *  the render motion at the pixel (render_motion), as the reference computes them, and
 *  with the depth rejection on (tau >= 0) whether the pixel keeps its history.
 *  @param[in]  mv   [2,h,w] float32 render-pixel motion
 *  @param[out] xy   [2 or 3,H,W8] float32, W8 = Wp rounded up to a multiple of 8 (whole
 *                   float8 loads): xs, then ys, then 1 / 0 (depth_keep; written only
 *                   with tau >= 0) (columns X >= W: those of X = W - 1)
 *  (the other arguments as nsrr_reproject's)
 *  NDRange: (W8 / 8, H). */
__kernel void nsrr_warp_coords(__global const float *mv, __global float *xy, int h, int w,
                               int H, int W, int Wp, float sy, float sx,
                               __global const float *dcur, __global const float *dprev,
                               float jy, float jx, float tau)
{
    const int X0 = get_global_id(0) * 8, Y = get_global_id(1), W8 = (Wp + 7) & ~7;
    if (X0 >= W8 || Y >= H) return;
    const long plane = (long)H * W8, o = (long)Y * W8 + X0;
    for (int l = 0; l < 8; ++l) {
        const int X = clss_mini(X0 + l, W - 1);
        const float2 m = render_motion(mv, h, w, X, Y, sy, sx);
        const float xs = (float)X + m.x * sx, ys = (float)Y + m.y * sy;
        xy[o + l] = xs;
        xy[plane + o + l] = ys;
        if (tau >= 0.0f)
            xy[2 * plane + o + l] = depth_keep(dcur, dprev, h, w, X, Y, xs, ys, sy, sx, jy, jx, tau)
                                    ? 1.0f : 0.0f;
    }
}

/* eight loads as one vector: LLVM may make it a gather */
#define GATHER8(p, i) ((float8)(FLD(p, (i).s0), FLD(p, (i).s1), FLD(p, (i).s2), FLD(p, (i).s3), \
                                FLD(p, (i).s4), FLD(p, (i).s5), FLD(p, (i).s6), FLD(p, (i).s7)))
/* the pairs (p[i], p[i + 1]) of 8 lanes as float, lane k's at .s(2k) and .s(2k+1) (clang
 * vectors: one 2-element load each; fp32 and fp16 storage) */
#if CLSS_CLANG_VECTORS && defined(__clang__) && !defined(CLSS_FP16_NATIVE)
#define PAIR_LOADS 1
typedef T Tv2u __attribute__((ext_vector_type(2), aligned(sizeof(T))));
#define PAIR(p, k) __builtin_convertvector(*(__global const Tv2u *)((p) + (k)), float2)
#define PAIRS8(p, i) ((float16)(PAIR(p, (i).s0), PAIR(p, (i).s1), PAIR(p, (i).s2), PAIR(p, (i).s3), \
                                PAIR(p, (i).s4), PAIR(p, (i).s5), PAIR(p, (i).s6), PAIR(p, (i).s7)))
#else
#define PAIR_LOADS 0
#endif
/* eight consecutive elements as float8 */
#if defined(CLSS_FP16_NATIVE)
#define LDF8(p, i) CLSS_CVT8(FLD8(p, i), float8)
#else
#define LDF8(p, i) FLD8(p, i)
#endif

__kernel void nsrr_reproject(__global const T *feat, __global const float *xy,
                             __global const T *hist, __global T *stack, __global T *base,
                             int h, int w, int H, int W, int Hp, int Wp, int nprev, int nvalid,
                             int siy, int six, int oy, int ox, float sy, float sx,
                             float jy, float jx, int mode, __global const float *dcur,
                             __global const float *dprev, float tau)
{
    const int Xw = get_global_id(0) * 8 * RUNS, Y = get_global_id(1), g = get_global_id(2);
    if (Xw >= Wp || Y >= Hp) return;
    const long oplane = (long)Hp * Wp, plane = (long)h * w;
    /* this group's planes of the stack: [c0, c0 + nc) (group 0 also writes base) */
    const int c0 = g == 0 ? 0 : FEAT + (g - 1) * G, nc = g == 0 ? FEAT : G;
    const int k = g == 0 ? -1 : (c0 - FEAT) / FEAT;        /* the history slot, -1 for Z_i */
    const float8 zero = (float8)(0.0f);
    const int i = zu_source(Y, h, siy, oy, sy, jy);
    for (int r = 0; r < RUNS; ++r) {
        const int X0 = Xw + 8 * r;
        if (X0 >= Wp) break;
        const int n = clss_mini(8, Wp - X0);
        const long o = (long)Y * Wp + X0;
        /* a history slot beyond the frames in use is empty too */
        if (Y >= H || X0 >= W || (g > 0 && mode == 0 && k >= nvalid)) {
            for (int c = 0; c < nc; ++c) PUT8(stack, (c0 + c) * oplane + o, zero, n);
            if (g == 0)
                for (int c = 0; c < 3; ++c) PUT8(base, c * oplane + o, zero, n);
            continue;
        }
        /* lanes at X >= W (the padding columns) are written 0; their loads use X = W - 1 */
        int8 in = (int8)(X0) + (int8)(0, 1, 2, 3, 4, 5, 6, 7) < (int8)(W);
        if (g > 0 && mode == 0) {      /* the history's warp: the frame's hot path */
            /* backward warp: this pixel was at (xs, ys) in the previous frame */
            const int W8 = (Wp + 7) & ~7;                   /* xy's row stride */
            const long xo = (long)Y * W8 + X0;
            if (tau >= 0.0f)            /* the depth rejection's lanes are written 0 too */
                in = in & (XLD8(xy + 2 * (long)H * W8 + xo) > (float8)(0.5f));
            const WarpTaps8 t = warp_taps8(XLD8(xy + xo), XLD8(xy + (long)H * W8 + xo), W, H);
            const int8 i00 = t.cy0 * Wp + t.cx0, i10 = t.cy0 * Wp + t.cx1;
            const int8 i01 = t.cy1 * Wp + t.cx0, i11 = t.cy1 * Wp + t.cx1;
            /* Where the run's taps are one 9 x 2 window (the usual case: motion varies
             * slowly along a row), its four taps are four vector loads at offsets 0, 1, Wp
             * and Wp + 1 of the window, the same elements the gathers read. */
            const int8 io = (int8)(0, 1, 2, 3, 4, 5, 6, 7);
            if (all8((i00 == (int8)(i00.s0) + io) & (i10 == i00 + 1) & (i01 == i00 + Wp) &
                     (i11 == i01 + 1))) {
                for (int c = 0; c < nc; ++c) {
                    __global const T *p = hist + (long)(c0 - FEAT + c) * oplane + i00.s0;
                    const float8 v = LDF8(p, 0) * t.w00 + LDF8(p, 1) * t.w10
                                     + LDF8(p, Wp) * t.w01 + LDF8(p, Wp + 1) * t.w11;
                    PUT8(stack, (c0 + c) * oplane + o, in ? v : zero, n);
                }
                continue;
            }
#if PAIR_LOADS
            /* each lane's two taps of a row are adjacent (away from the right edge's clamp):
             * one 2-element load per lane and row, half the loads of the gathers */
            if (all8((i10 == i00 + 1) & (i11 == i01 + 1))) {
                for (int c = 0; c < nc; ++c) {
                    __global const T *p = hist + (long)(c0 - FEAT + c) * oplane;
                    const float16 tp = PAIRS8(p, i00), bt = PAIRS8(p, i01);
                    const float8 v = tp.even * t.w00 + tp.odd * t.w10 + bt.even * t.w01 + bt.odd * t.w11;
                    PUT8(stack, (c0 + c) * oplane + o, in ? v : zero, n);
                }
                continue;
            }
#endif
            for (int c = 0; c < nc; ++c) {
                __global const T *p = hist + (long)(c0 - FEAT + c) * oplane;
                const float8 v = GATHER8(p, i00) * t.w00 + GATHER8(p, i10) * t.w10
                                 + GATHER8(p, i01) * t.w01 + GATHER8(p, i11) * t.w11;
                PUT8(stack, (c0 + c) * oplane + o, in ? v : zero, n);
            }
            continue;
        }
        int xl[8];
        for (int q = 0; q < 8; ++q) xl[q] = clss_mini(X0 + q, W - 1);
        if (g == 0) {
            const AxisTaps bv = axis_taps(((float)Y + 0.5f) / sy - 0.5f - jy, h);
            const int r0 = bv.i0, r1 = bv.i1;
            const float fc = bv.f;
            float tb[8], bb[8];
            for (int c = 0; c < 3; ++c) {
                __global const T *q = feat + c * plane;
                for (int l = 0; l < 8; ++l) {
                    const AxisTaps bu = axis_taps(((float)xl[l] + 0.5f) / sx - 0.5f - jx, w);
                    const int b0 = bu.i0, b1 = bu.i1;
                    const float fb = bu.f;
                    tb[l] = FLD(q, (long)r0 * w + b0) * (1.0f - fb) + FLD(q, (long)r0 * w + b1) * fb;
                    bb[l] = FLD(q, (long)r1 * w + b0) * (1.0f - fb) + FLD(q, (long)r1 * w + b1) * fb;
                }
                const float8 v = PLD8(tb) * (float8)(1.0f - fc) + PLD8(bb) * (float8)(fc);
                PUT8(base, c * oplane + o, in ? v : zero, n);
            }
        }
        /* Z_i (group 0), or a reset's slot: zeros, or Z_i again (mode 2, k < nvalid) */
        const bool z = g == 0 || (mode == 2 && k < nvalid);
        long src[8];
        for (int l = 0; l < 8; ++l) {
            const int j = (i < 0 || !z) ? -1 : zu_source(xl[l], w, six, ox, sx, jx);
            src[l] = (j < 0 || X0 + l >= W) ? -1 : (long)i * w + j;
        }
        for (int c = 0; c < nc; ++c) {
            const int fc = g == 0 ? c : (c0 + c) % FEAT;     /* the feature channel */
            float t[8];
            for (int l = 0; l < 8; ++l)
                t[l] = src[l] < 0 ? 0.0f : FLD(feat, fc * plane + src[l]);
            PUT8(stack, (c0 + c) * oplane + o, PLD8(t), n);
        }
    }
}
#endif

/** The output, 8 pixels of a row per work-item so that the PQ decode runs on float8
 *  (pq_decode8: the scalar exp2/log2 are library calls on PoCL, 327 ms of a 1080p frame).
 *  @param[in]  y            [3,Hp,Wp] T: the network's output, PQ
 *  @param[out] out          [H,W,3] float32 linear (times exposure)
 *  @param[in]  H            output height
 *  @param[in]  W            output width
 *  @param[in]  Wp           padded width (row stride of y)
 *  @param[in]  Hp           padded height
 *  @param[in]  inv_pq_scale 10000 / nits, times the exposure
 *  NDRange: (ceil(W / 8), H). */
__kernel void nsrr_finish(__global const T *y, __global float *out, int H, int W, int Wp, int Hp,
                          float inv_pq_scale)
{
    const int X0 = get_global_id(0) * 8, Y = get_global_id(1);
    if (X0 >= W || Y >= H) return;
    const int n = min(8, W - X0);
    const long plane = (long)Hp * Wp, p = (long)Y * Wp + X0;
    __global float *o = out + 3 * ((long)Y * W + X0);
    for (int c = 0; c < 3; ++c) {
        float8 e;
        if (X0 + 8 <= Wp) {             /* the padding columns are read and not written */
            e = CLSS_CVT8(FLD8(y, c * plane + p), float8);
        } else {
            float t[8];
            for (int k = 0; k < 8; ++k)
                t[k] = k < n ? (float)LD(y, c * plane + p + k) : 0.0f;
            e = PLD8(t);
        }
        float d[8];
        PST8(d, pq_decode8(e, inv_pq_scale));
        for (int k = 0; k < n; ++k)
            o[3 * k + c] = d[k];
    }
}
