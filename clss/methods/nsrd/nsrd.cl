/* NSRD's frame step around its network (Li et al. 2024, section 3; the room
 * clss/methods/nsrd/, whose ONNX twin oracle.py states the same formulas as graph nodes
 * and whose torch twin is weights_tools/nsrd_torch.py).
 *
 *   nsrd_encode   render resolution, 8 pixels a work-item (fast path nsrd.encode8): the
 *                 lighting's PQ encode on float8, which nsrd_prepare then leaves out
 *   nsrd_alpha    the learned re-modulation's sigmoid on float8 (the same fast path),
 *                 which nsrd_finish then reads
 *   nsrd_prepare  render resolution: demodulation (lighting = colour / material, PQ),
 *                 the previous state warped by the motion (bilinear, zero outside), the
 *                 occlusion mask from the reprojected-depth test, the network's inputs
 *                 cur [10,hp,wp] and warp [8,hp,wp], and the next state [8,h,w]
 *   nsrd_prev     output resolution: the previous output's lighting warped by the
 *                 bilinearly upsampled motion, pixel-unshuffled to prev [3s^2,hp,wp]
 *   nsrd_finish   output resolution: the network's sub-pixel output shuffled to H x W,
 *                 plus the current lighting at the output pixel centres (bilinear, or guided_base)
 *                 (jitter-aware), clipped to [0, 1] (the next frame's history), and the
 *                 output-resolution material (albedo_hr filtered 3x3 binomial, see
 *                 networks.MATERIAL_FILTER) into out
 *   nsrd_decode   output resolution, 8 pixels a work-item: out *= the PQ-decoded lighting
 *                 (float8: scalar exp2/log2 are library calls on PoCL)
 *   nsrd_rules_in, nsrd_rules_mix   the rules' base only (networks.OUT_BASES): clss-rules'
 *                 PQ colour unshuffled into prev beside the previous output; the output
 *                 moved from the rules' towards NSRD's by the clamped mix
 *
 * The state (float32, render resolution): channels 0-2 the lighting L_i (PQ), 3 the mask
 * M_i (frame i-1 valid at frame i), 4-6 A_i = L_{i-1} warped to frame i, 7 depth. One
 * warp by frame i+1's motion brings L_i and A_i (= frame i-2's lighting, warped twice:
 * the accumulative warping) and M_i to frame i+1.
 *
 * keep = 0 on a reset: every warped quantity (and the mask) is 0 that frame.
 */
#include "common.h"

#pragma OPENCL FP_CONTRACT OFF

#define STATE 8
#define CUR 10
#define WARP 8

/* -DNSRD_SCALE=s: the scale as a constant (the host builds one program per scale), so the
 * output kernels' X / s and X % s are shifts and multiplies, not integer divisions (a third
 * of nsrd_prev's time at 4x on PoCL); without it, the kernel argument. */
#ifdef NSRD_SCALE
#define SCALE_OR(arg) NSRD_SCALE
#else
#define SCALE_OR(arg) (arg)
#endif

#include "pq.h"
#include "warp_taps.h"     /* includes inline_math.h: -DCLSS_INLINE_MATH, fast path nsrd.inline_math */

/* The material of one channel: the albedo, or 1 where it is below eps (black, sky). */
static float material(float a, int demod, float eps)
{
    return (demod && a >= eps) ? a : 1.0f;
}


static float fin(float v, float fill)
{
    return clss_isfinite(v) ? v : fill;
}

/* nsrd_prepare's arguments (and nsrd_prepare8's: the host binds them alike) */
#define NSRD_PREPARE_ARGS                                                                     \
    __global const float *color, __global const float *depth, __global const float *motion,   \
    __global const float *albedo, __global const float *normal, __global const float *state_old, \
    __global float *state_new, __global T *cur, __global T *warp, __global float *mv, int w,   \
    int h, int wp, int hp, int depth_inverted, float msx, float msy, float inv_exposure,       \
    float pq_scale, float keep, int demod, int use_mask, float eps, float tol, float dfloor,   \
    __global const T *h_in, __global const T *c_in, __global T *h_w, __global T *c_w, int hid, \
    int warp_state

/** @param[in]  color, depth, motion  the caller's frame (image layout, float32)
 *  @param[in]  albedo, normal        [h,w,3] float32 G-buffers
 *  @param[in]  state_old             [8,h,w] float32 the previous frame's state
 *  @param[out] state_new             [8,h,w] float32
 *  @param[out] cur                   [10,hp,wp] T: L (PQ), albedo, normal, depth; 0 in the padding
 *  @param[out] warp                  [8,hp,wp] T: w1, v1, w2, v2; 0 in the padding
 *  @param[out] mv                    [2,h,w] float32 motion in render pixels
 *  keep: 0 on a reset, else 1; demod / use_mask: the config's (ablations); tol, floor
 *  and eps the constants of networks.py.
 *  NDRange: (wp, hp). */
__kernel void nsrd_prepare(NSRD_PREPARE_ARGS)
{
    const int x = get_global_id(0), y = get_global_id(1);
    if (x >= wp || y >= hp) return;
    const long np_ = (long)hp * wp, q = (long)y * wp + x;
    if (x >= w || y >= h) {
        for (int c = 0; c < CUR; ++c) ST(cur, c * np_ + q, 0.0f);
        for (int c = 0; c < WARP; ++c) ST(warp, c * np_ + q, 0.0f);
        for (int c = 0; c < (warp_state ? hid : 0); ++c) {
            ST(h_w, c * np_ + q, 0.0f);
            ST(c_w, c * np_ + q, 0.0f);
        }
        return;
    }
    const int p = y * w + x, plane = w * h;
    for (int c = 0; c < 3; ++c) {
        const float a = fin(albedo[3 * p + c], 0.0f);
#if NSRD_ENCODE8
        /* the lighting: nsrd_encode wrote it (cur and state_new), 8 pixels at a time */
#else
        const float v = fin(color[3 * p + c], 0.0f) * inv_exposure;
        const float L = pq_encode(v / material(a, demod, eps), pq_scale);
        ST(cur, c * np_ + q, L);
        state_new[c * plane + p] = L;
#endif
        ST(cur, (3 + c) * np_ + q, a);
        ST(cur, (6 + c) * np_ + q, fin(normal[3 * p + c], 0.0f));
    }
    float d = fin(depth[p], depth_inverted ? 0.0f : 1.0f);
    d = depth_inverted ? d : 1.0f - d;
    ST(cur, 9 * np_ + q, d);
    const float mx = fin(motion[2 * p], 0.0f) * msx, my = fin(motion[2 * p + 1], 0.0f) * msy;
    mv[p] = mx;
    mv[plane + p] = my;
    /* the previous state at this pixel's previous position (bilinear, zero outside) */
    const float xs = (float)x + mx, ys = (float)y + my;
    const WarpTaps t = warp_taps(xs, ys, w, h);
    const float w00 = t.w00, w10 = t.w10, w01 = t.w01, w11 = t.w11;
    const int cx0 = t.cx0, cx1 = t.cx1, cy0 = t.cy0, cy1 = t.cy1;
    float s[STATE];
    for (int c = 0; c < STATE; ++c) {
        __global const float *o = state_old + c * plane;
        s[c] = o[cy0 * w + cx0] * w00 + o[cy0 * w + cx1] * w10 + o[cy1 * w + cx0] * w01
             + o[cy1 * w + cx1] * w11;
    }
    float m = 1.0f;
    if (use_mask) {
        const float rel = clss_fabsf(s[7] - d) / (tol * clss_fmaxf(d, s[7]) + dfloor);
        m = clss_clampf(2.0f - rel, 0.0f, 1.0f);
    }
    m = m * keep;
    for (int c = 0; c < 3; ++c) {
        const float w1 = s[c] * keep, w2 = s[4 + c] * keep;
        ST(warp, c * np_ + q, w1);
        ST(warp, (4 + c) * np_ + q, w2);
        state_new[(4 + c) * plane + p] = w1;
    }
    ST(warp, 3 * np_ + q, m);
    ST(warp, 7 * np_ + q, m * s[3]);
    state_new[3 * plane + p] = m;
    state_new[7 * plane + p] = d;
    /* warp_state: the ConvLSTM's h and c warped like the state (render region only, zero
     * outside it and in the padding), so the cell's memory follows the motion */
    for (int c = 0; c < (warp_state ? hid : 0); ++c) {
        const long b = c * np_;
        const long a00 = (long)cy0 * wp + cx0, a10 = (long)cy0 * wp + cx1;
        const long a01 = (long)cy1 * wp + cx0, a11 = (long)cy1 * wp + cx1;
        const float hv = LD(h_in, b + a00) * w00 + LD(h_in, b + a10) * w10
                       + LD(h_in, b + a01) * w01 + LD(h_in, b + a11) * w11;
        const float cv = LD(c_in, b + a00) * w00 + LD(c_in, b + a10) * w10
                       + LD(c_in, b + a01) * w01 + LD(c_in, b + a11) * w11;
        ST(h_w, b + q, hv * keep);
        ST(c_w, b + q, cv * keep);
    }
}

/* -DNSRD_ENCODE8=1 (fast path nsrd.encode8): the lighting's PQ encode runs in
 * nsrd_encode on float8, 8 pixels a work-item, before nsrd_prepare (which then leaves it
 * out). Per pixel, scalar exp2 and log2 are library calls on PoCL: the encode's six of them
 * were half of nsrd_prepare's time. */
#ifndef NSRD_ENCODE8
#define NSRD_ENCODE8 0
#endif

static float8 fin8(float8 v, float fill)
{
    return (v - v) == (float8)(0.0f) ? v : (float8)(fill);     /* as clss_isfinite */
}

/* material on float8 lanes, as the scalar material() */
static float8 material8(float8 a, int demod, float eps)
{
    return demod ? (a >= eps ? a : (float8)(1.0f)) : (float8)(1.0f);
}

static PQ_ENCODE(float8, pq_encode8, powp8)

/** nsrd_prepare for 8 pixels of a row (NSRD_ENCODE8; nsrd_encode wrote the lighting): the
 *  same operations on float8 lanes (warp_taps8), bit-identical to nsrd_prepare. Lanes past
 *  the render width compute on its last pixel and store the padding's zeros. Arguments as
 *  nsrd_prepare. NDRange: (ceil(wp / 8), hp). */
__kernel void nsrd_prepare8(NSRD_PREPARE_ARGS)
{
    const int x0 = get_global_id(0) * 8, y = get_global_id(1);
    if (x0 >= wp || y >= hp) return;
    const long np_ = (long)hp * wp, q0 = (long)y * wp + x0;
    const int nq = min(8, wp - x0);             /* lanes inside the padded row */
    if (y >= h || x0 >= w) {
        for (int k = 0; k < nq; ++k) {
            for (int c = 0; c < CUR; ++c) ST(cur, c * np_ + q0 + k, 0.0f);
            for (int c = 0; c < WARP; ++c) ST(warp, c * np_ + q0 + k, 0.0f);
        }
        return;
    }
    const int n = min(8, w - x0);               /* lanes inside the render width */
    const int plane = w * h;
    const int8 xi = (int8)(x0) + (int8)(0, 1, 2, 3, 4, 5, 6, 7);
    const int8 xc = xi < w - 1 ? xi : (int8)(w - 1);
    const long8 p = (long8)((long)y * w) + CLSS_CVT8(xc, long8);
    float vals[CUR + WARP][8];      /* cur then warp, per lane, stored at the end */
    for (int c = 0; c < 3; ++c) {
        const float8 a = fin8(CLSS_GATHER8(albedo + c, 3 * p), 0.0f);
        PST8(vals[3 + c], a);
        PST8(vals[6 + c], fin8(CLSS_GATHER8(normal + c, 3 * p), 0.0f));
    }
    float8 d = fin8(CLSS_GATHER8(depth, p), depth_inverted ? 0.0f : 1.0f);
    d = depth_inverted ? d : 1.0f - d;
    PST8(vals[9], d);
    const float8 mx = fin8(CLSS_GATHER8(motion, 2 * p), 0.0f) * msx;
    const float8 my = fin8(CLSS_GATHER8(motion + 1, 2 * p), 0.0f) * msy;
    const float8 xs = CLSS_CVT8(xi, float8) + mx, ys = (float8)((float)y) + my;
    const WarpTaps8 t = warp_taps8(xs, ys, w, h);
    const long8 a00 = CLSS_CVT8(t.cy0, long8) * w + CLSS_CVT8(t.cx0, long8);
    const long8 a10 = CLSS_CVT8(t.cy0, long8) * w + CLSS_CVT8(t.cx1, long8);
    const long8 a01 = CLSS_CVT8(t.cy1, long8) * w + CLSS_CVT8(t.cx0, long8);
    const long8 a11 = CLSS_CVT8(t.cy1, long8) * w + CLSS_CVT8(t.cx1, long8);
    float8 sv[STATE];
    for (int c = 0; c < STATE; ++c) {
        __global const float *o = state_old + c * plane;
        sv[c] = CLSS_GATHER8(o, a00) * t.w00 + CLSS_GATHER8(o, a10) * t.w10 + CLSS_GATHER8(o, a01) * t.w01
              + CLSS_GATHER8(o, a11) * t.w11;
    }
    float8 m = (float8)(1.0f);
    if (use_mask) {
        const float8 diff = sv[7] - d;
        const float8 ad = as_float8(as_uint8(diff) & (uint8)(0x7fffffffu));
        const float8 rel = ad / (tol * (d > sv[7] ? d : sv[7]) + dfloor);
        const float8 r = 2.0f - rel;
        m = r > 0.0f ? (r < 1.0f ? r : (float8)(1.0f)) : (float8)(0.0f);
    }
    m = m * keep;
    float sn[5][8];                 /* state_new channels 3-7 */
    for (int c = 0; c < 3; ++c) {
        const float8 w1 = sv[c] * keep, w2 = sv[4 + c] * keep;
        PST8(vals[CUR + c], w1);
        PST8(vals[CUR + 4 + c], w2);
        PST8(sn[1 + c], w1);
    }
    PST8(vals[CUR + 3], m);
    PST8(vals[CUR + 7], m * sv[3]);
    PST8(sn[0], m);
    PST8(sn[4], d);
    for (int k = 0; k < nq; ++k) {
        const int in = k < n;
        for (int c = 3; c < CUR; ++c) ST(cur, c * np_ + q0 + k, in ? vals[c][k] : 0.0f);
        if (!in) {
            for (int c = 0; c < 3; ++c) ST(cur, c * np_ + q0 + k, 0.0f);
        }
        for (int c = 0; c < WARP; ++c) ST(warp, c * np_ + q0 + k, in ? vals[CUR + c][k] : 0.0f);
    }
    const int p0 = y * w + x0;
    float mxs[8], mys[8];
    PST8(mxs, mx);
    PST8(mys, my);
    for (int k = 0; k < n; ++k) {
        mv[p0 + k] = mxs[k];
        mv[plane + p0 + k] = mys[k];
        for (int c = 0; c < 5; ++c)
            state_new[(3 + c) * plane + p0 + k] = sn[c][k];
    }
    /* warp_state: nsrd_warp_state8 warps h and c, a channel a work-item */
}

/** NSRD_ENCODE8's warp of the ConvLSTM's h and c (warp_state), for nsrd_prepare8: channel
 *  by channel (one per work-item along NDRange dimension 2), so each work-group streams two
 *  planes in and two out instead of all of them at once; the taps again from mv, which
 *  nsrd_prepare8 wrote (the same values nsrd_prepare warps with). Zero outside the render
 *  region, as nsrd_prepare.
 *  @param[in]  mv    [2,h,w] float32 (nsrd_prepare8)
 *  @param[in]  h_in, c_in  [hid,hp,wp] T
 *  @param[out] h_w, c_w    [hid,hp,wp] T
 *  NDRange: (ceil(wp / 8), hp, hid). */
__kernel void nsrd_warp_state8(__global const float *mv, __global const T *h_in, __global const T *c_in,
                               __global T *h_w, __global T *c_w, int w, int h, int wp, int hp, float keep)
{
    const int x0 = get_global_id(0) * 8, y = get_global_id(1), c = get_global_id(2);
    if (x0 >= wp || y >= hp) return;
    const long np_ = (long)hp * wp, b = c * np_, q0 = (long)y * wp + x0;
    const int nq = min(8, wp - x0);
    if (y >= h || x0 >= w) {
        for (int k = 0; k < nq; ++k) {
            ST(h_w, b + q0 + k, 0.0f);
            ST(c_w, b + q0 + k, 0.0f);
        }
        return;
    }
    const int n = min(8, w - x0), plane = w * h;
    const int8 xi = (int8)(x0) + (int8)(0, 1, 2, 3, 4, 5, 6, 7);
    const int8 xc = xi < w - 1 ? xi : (int8)(w - 1);
    const long8 p = (long8)((long)y * w) + CLSS_CVT8(xc, long8);
    const float8 xs = CLSS_CVT8(xi, float8) + CLSS_GATHER8(mv, p);
    const float8 ys = (float8)((float)y) + CLSS_GATHER8(mv + plane, p);
    const WarpTaps8 t = warp_taps8(xs, ys, w, h);
    const long8 b00 = CLSS_CVT8(t.cy0, long8) * wp + CLSS_CVT8(t.cx0, long8);
    const long8 b10 = CLSS_CVT8(t.cy0, long8) * wp + CLSS_CVT8(t.cx1, long8);
    const long8 b01 = CLSS_CVT8(t.cy1, long8) * wp + CLSS_CVT8(t.cx0, long8);
    const long8 b11 = CLSS_CVT8(t.cy1, long8) * wp + CLSS_CVT8(t.cx1, long8);
#define LD8AT(p_, i) ((float8)(LD(p_, b + (i).s0), LD(p_, b + (i).s1), LD(p_, b + (i).s2), LD(p_, b + (i).s3), \
                               LD(p_, b + (i).s4), LD(p_, b + (i).s5), LD(p_, b + (i).s6), LD(p_, b + (i).s7)))
    const float8 hv = LD8AT(h_in, b00) * t.w00 + LD8AT(h_in, b10) * t.w10
                    + LD8AT(h_in, b01) * t.w01 + LD8AT(h_in, b11) * t.w11;
    const float8 cv = LD8AT(c_in, b00) * t.w00 + LD8AT(c_in, b10) * t.w10
                    + LD8AT(c_in, b01) * t.w01 + LD8AT(c_in, b11) * t.w11;
#undef LD8AT
    float hs[8], cs[8];
    PST8(hs, hv * keep);
    PST8(cs, cv * keep);
    for (int k = 0; k < nq; ++k) {
        ST(h_w, b + q0 + k, k < n ? hs[k] : 0.0f);
        ST(c_w, b + q0 + k, k < n ? cs[k] : 0.0f);
    }
}

/** The lighting L = PQ(colour / material) of 8 pixels of a row (NSRD_ENCODE8), into cur's
 *  channels 0-2 and state_new's.
 *  @param[in]  color, albedo  [h,w,3] float32
 *  @param[out] cur            [10,hp,wp] T: channels 0-2
 *  @param[out] state_new      [8,h,w] float32: channels 0-2
 *  NDRange: (ceil(w / 8), h). */
__kernel void nsrd_encode(__global const float *color, __global const float *albedo, __global T *cur,
                          __global float *state_new, int w, int h, int wp, int hp,
                          float inv_exposure, float pq_scale, int demod, float eps)
{
    const int x0 = get_global_id(0) * 8, y = get_global_id(1);
    if (x0 >= w || y >= h) return;
    const int n = min(8, w - x0), p0 = y * w + x0;
    const long np_ = (long)hp * wp, q0 = (long)y * wp + x0;
    float cs[24], as[24];
    for (int k = 0; k < 24; ++k) {
        cs[k] = k < 3 * n ? color[3 * p0 + k] : 0.0f;
        as[k] = k < 3 * n ? albedo[3 * p0 + k] : 0.0f;
    }
    for (int c = 0; c < 3; ++c) {
        const float8 col = (float8)(cs[c], cs[3 + c], cs[6 + c], cs[9 + c], cs[12 + c], cs[15 + c],
                                    cs[18 + c], cs[21 + c]);
        const float8 alb = (float8)(as[c], as[3 + c], as[6 + c], as[9 + c], as[12 + c], as[15 + c],
                                    as[18 + c], as[21 + c]);
        const float8 a = fin8(alb, 0.0f);
        const float8 m = material8(a, demod, eps);
        float L[8];
        PST8(L, pq_encode8(fin8(col, 0.0f) * inv_exposure / m, pq_scale));
        for (int k = 0; k < n; ++k) {
            ST(cur, c * np_ + q0 + k, L[k]);
            state_new[c * h * w + p0 + k] = L[k];
        }
    }
}

/** alpha = sigmoid(the learned re-modulation's logits) on float8 (NSRD_ENCODE8), for
 *  nsrd_finish: per output pixel, the scalar exp was a library call.
 *  @param[in]  y      [3s^2 + s^2, hp, wp] T: the network's output
 *  @param[out] alpha  [s^2, hp, wp] float32
 *  @param[in]  off    3 s^2 hp wp, the first logit
 *  @param[in]  n      s^2 hp wp
 *  NDRange: (ceil(n / 8)). */
__kernel void nsrd_alpha(__global const T *y, __global float *alpha, int off, int n)
{
    const int i0 = get_global_id(0) * 8;
    if (i0 >= n) return;
    const int m = min(8, n - i0);
    float z[8];
    for (int k = 0; k < 8; ++k)
        z[k] = LD(y, off + i0 + min(k, m - 1));
    float a[8];
    PST8(a, 1.0f / (1.0f + exp(-PLD8(z))));
    for (int k = 0; k < m; ++k)
        alpha[i0 + k] = a[k];
}

/** @param[in]  hist  [3,H,W] float32 the previous output's lighting (PQ)
 *  @param[in]  mv    [2,h,w] float32 render-pixel motion
 *  @param[out] prev  [3s^2,hp,wp] T: hist warped, pixel-unshuffled (channel c*s*s + i*s + j)
 *  NDRange: (W, H); H = h s, W = w s. */
__kernel void nsrd_prev(__global const float *hist, __global const float *mv, __global T *prev,
                        int h, int w, int H, int W, int hp, int wp, int s_, float keep)
{
    const int s = SCALE_OR(s_);
    const int X = get_global_id(0), Y = get_global_id(1);
    if (X >= W || Y >= H) return;
    const float fs = (float)s;
    /* the render motion here: bilinear, half-pixel centres, edge-clamped (ONNX Resize
     * linear half_pixel, torch interpolate align_corners=False), in output pixels */
    float u = ((float)X + 0.5f) / fs - 0.5f, v = ((float)Y + 0.5f) / fs - 0.5f;
    u = clss_clampf(u, 0.0f, (float)(w - 1));
    v = clss_clampf(v, 0.0f, (float)(h - 1));
    const int u0 = clss_floori(u), v0 = clss_floori(v);
    const int u1 = clss_mini(u0 + 1, w - 1), v1 = clss_mini(v0 + 1, h - 1);
    const float fu = u - (float)u0, fv = v - (float)v0;
    const int plane = h * w;
    float m[2];
    for (int c = 0; c < 2; ++c) {
        __global const float *q = mv + c * plane;
        const float top = q[v0 * w + u0] * (1.0f - fu) + q[v0 * w + u1] * fu;
        const float bot = q[v1 * w + u0] * (1.0f - fu) + q[v1 * w + u1] * fu;
        m[c] = (top * (1.0f - fv) + bot * fv) * fs;
    }
    const float xs = (float)X + m[0], ys = (float)Y + m[1];
    const WarpTaps t = warp_taps(xs, ys, W, H);
    const float w00 = t.w00, w10 = t.w10, w01 = t.w01, w11 = t.w11;
    const int cx0 = t.cx0, cx1 = t.cx1, cy0 = t.cy0, cy1 = t.cy1;
    const long P = (long)H * W, np_ = (long)hp * wp;
    const long o = (long)(Y / s) * wp + X / s;
    const int sub = (Y % s) * s + X % s;
    for (int c = 0; c < 3; ++c) {
        __global const float *q = hist + c * P;
        const float r = q[(long)cy0 * W + cx0] * w00 + q[(long)cy0 * W + cx1] * w10
                      + q[(long)cy1 * W + cx0] * w01 + q[(long)cy1 * W + cx1] * w11;
        ST(prev, (c * s * s + sub) * np_ + o, r * keep);
    }
}

/* The two render-resolution taps along x of 8 output pixels and the weight of the second:
 * the position u (render pixels) clamped to [0, n - 1], its floor, the next index (clamped)
 * and the fraction, as the per-pixel kernels compute them (clss_clampf, clss_floori,
 * clss_mini) */
typedef struct {
    int8 i0, i1;
    float8 f;
} RenderAxis8;

static RenderAxis8 render_axis8(float8 u, int n)
{
    RenderAxis8 a;
    u = u > 0.0f ? (u < (float)(n - 1) ? u : (float8)((float)(n - 1))) : (float8)(0.0f);
    a.i0 = clss_floori8(u);
    a.i1 = a.i0 + 1 < n - 1 ? a.i0 + 1 : (int8)(n - 1);
    a.f = u - CLSS_CVT8(a.i0, float8);
    return a;
}

/** nsrd_prev for 8 output pixels of a row (NSRD_ENCODE8): the same operations on float8
 *  lanes (warp_taps8), bit-identical to nsrd_prev. Arguments as nsrd_prev.
 *  NDRange: (ceil(W / 8), H). */
__kernel void nsrd_prev8(__global const float *hist, __global const float *mv, __global T *prev,
                         int h, int w, int H, int W, int hp, int wp, int s_, float keep)
{
    const int s = SCALE_OR(s_);
    const int X0 = get_global_id(0) * 8, Y = get_global_id(1);
    if (X0 >= W || Y >= H) return;
    const int n = min(8, W - X0);
    const float fs = (float)s;
    const float8 Xf = (float8)((float)X0) + (float8)(0.0f, 1.0f, 2.0f, 3.0f, 4.0f, 5.0f, 6.0f, 7.0f);
    const RenderAxis8 ax = render_axis8((Xf + 0.5f) / fs - 0.5f, w);
    const int8 u0 = ax.i0, u1 = ax.i1;
    const float8 fu = ax.f;
    float v = ((float)Y + 0.5f) / fs - 0.5f;
    v = clss_clampf(v, 0.0f, (float)(h - 1));
    const int v0 = clss_floori(v);
    const int v1 = clss_mini(v0 + 1, h - 1);
    const float fv = v - (float)v0;
    const int plane = h * w;
    float8 m[2];
    for (int c = 0; c < 2; ++c) {
        __global const float *q = mv + c * plane;
        const long8 r0 = (long8)((long)v0 * w) + CLSS_CVT8(u0, long8);
        const long8 r0b = (long8)((long)v0 * w) + CLSS_CVT8(u1, long8);
        const long8 r1 = (long8)((long)v1 * w) + CLSS_CVT8(u0, long8);
        const long8 r1b = (long8)((long)v1 * w) + CLSS_CVT8(u1, long8);
        const float8 top = CLSS_GATHER8(q, r0) * (1.0f - fu) + CLSS_GATHER8(q, r0b) * fu;
        const float8 bot = CLSS_GATHER8(q, r1) * (1.0f - fu) + CLSS_GATHER8(q, r1b) * fu;
        m[c] = (top * (1.0f - fv) + bot * fv) * fs;
    }
    const float8 xs = Xf + m[0], ys = (float8)((float)Y) + m[1];
    const WarpTaps8 t = warp_taps8(xs, ys, W, H);
    const long P = (long)H * W, np_ = (long)hp * wp;
    const long8 a00 = CLSS_CVT8(t.cy0, long8) * W + CLSS_CVT8(t.cx0, long8);
    const long8 a10 = CLSS_CVT8(t.cy0, long8) * W + CLSS_CVT8(t.cx1, long8);
    const long8 a01 = CLSS_CVT8(t.cy1, long8) * W + CLSS_CVT8(t.cx0, long8);
    const long8 a11 = CLSS_CVT8(t.cy1, long8) * W + CLSS_CVT8(t.cx1, long8);
    for (int c = 0; c < 3; ++c) {
        __global const float *q = hist + c * P;
        const float8 r = CLSS_GATHER8(q, a00) * t.w00 + CLSS_GATHER8(q, a10) * t.w10
                       + CLSS_GATHER8(q, a01) * t.w01 + CLSS_GATHER8(q, a11) * t.w11;
        float rs[8];
        PST8(rs, r * keep);
        for (int k = 0; k < n; ++k) {
            const int X = X0 + k;
            ST(prev, (c * s * s + (Y % s) * s + X % s) * np_ + (long)(Y / s) * wp + X / s, rs[k]);
        }
    }
}

/* The guided base (networks.BASES "guided", GUIDE_*): the lighting at output pixel Q,
 * whose centre lies at (bu, bv) in the render frame (clamped to it), as the mean of the
 * 4 x 4 render samples around it weighted by a tent of radius 2 times
 * exp(-|m_q - m_p|^2 / GUIDE_SIGMA^2) + GUIDE_FLOOR, m_p the point material at Q:
 * bilinear lighting mixes both sides of a material edge, which re-modulation turns
 * into halos. Tap order and arithmetic as networks.guide_taps. */
/* -DNSRD_GUIDE_INV_SIG2, -DNSRD_GUIDE_FLOOR: networks.GUIDE_* (frame.guide_defines) */
static void guided_base(__global const float *state, __global const float *albedo,
                        __global const float *albedo_hr, int h, int w, long Q,
                        float bu, float bv, int demod, float eps, float *out)
{
    const int b0 = clss_floori(bu), c0 = clss_floori(bv);
    float mp[3], acc[3] = {0.0f, 0.0f, 0.0f}, ws = 0.0f;
    for (int c = 0; c < 3; ++c)
        mp[c] = material(fin(albedo_hr[3 * Q + c], 0.0f), demod, eps);
    for (int dy = -1; dy <= 2; ++dy) {
        const int ty = c0 + dy;
        const float dv = bv - (float)ty;
        const float ty_ = 1.0f - (dv < 0.0f ? -dv : dv) * 0.5f, wy = ty_ > 0.0f ? ty_ : 0.0f;
        const long row = (long)clss_clampi(ty, 0, h - 1) * w;
        for (int dx = -1; dx <= 2; ++dx) {
            const int tx = b0 + dx;
            const float du = bu - (float)tx;
            const float tx_ = 1.0f - (du < 0.0f ? -du : du) * 0.5f, wx = tx_ > 0.0f ? tx_ : 0.0f;
            const long q = row + clss_clampi(tx, 0, w - 1);
            float d2 = 0.0f;
            for (int c = 0; c < 3; ++c) {
                const float d = material(fin(albedo[3 * q + c], 0.0f), demod, eps) - mp[c];
                d2 += d * d;
            }
            const float wt = wy * wx * (exp(-d2 * NSRD_GUIDE_INV_SIG2) + NSRD_GUIDE_FLOOR);
            for (int c = 0; c < 3; ++c)
                acc[c] += wt * state[(long)c * h * w + q];
            ws += wt;
        }
    }
    for (int c = 0; c < 3; ++c)
        out[c] = acc[c] / ws;
}

/** @param[in]  y          [3s^2,hp,wp] T: the network's output
 *  @param[in]  state      [8,h,w] float32: this frame's state (channels 0-2: the lighting)
 *  @param[in]  albedo_hr  [H,W,3] float32
 *  @param[out] hist       [3,H,W] float32: the output lighting (PQ, in [0, 1])
 *  @param[out] out        [H,W,3] float32 the material (nsrd_decode multiplies in the lighting)
 *  learned: 1 = y has s^2 more channels, the logits of alpha: the material is then
 *  alpha * point + (1 - alpha) * filtered (networks.REMODS)
 *  @param[in]  alpha8     [s^2,hp,wp] float32: alpha (nsrd_alpha), read with NSRD_ENCODE8
 *  NDRange: (W, H). */
__kernel void nsrd_finish(__global const T *y, __global const float *state,
                          __global const float *albedo_hr, __global float *hist,
                          __global float *out, int h, int w, int H, int W, int hp, int wp, int s_,
                          float jx, float jy, int demod, float eps,
                          int learned, __global const float *alpha8,
                          __global const float *albedo, int guided)
{
    const int s = SCALE_OR(s_);
    const int X = get_global_id(0), Y = get_global_id(1);
    if (X >= W || Y >= H) return;
    const float fs = (float)s;
    const float bu = clss_clampf(((float)X + 0.5f) / fs - 0.5f - jx, 0.0f, (float)(w - 1));
    const float bv = clss_clampf(((float)Y + 0.5f) / fs - 0.5f - jy, 0.0f, (float)(h - 1));
    const int b0 = clss_floori(bu), c0 = clss_floori(bv);
    const int b1 = clss_mini(b0 + 1, w - 1), c1 = clss_mini(c0 + 1, h - 1);
    const float fb = bu - (float)b0, fc = bv - (float)c0;
    const long np_ = (long)hp * wp, o = (long)(Y / s) * wp + X / s, P = (long)H * W;
    const long Q = (long)Y * W + X;
    const int sub = (Y % s) * s + X % s;
    /* the material: albedo_hr filtered by the 3x3 binomial (networks.MATERIAL_FILTER),
     * edge-clamped, then the eps rule */
    const int xm = clss_maxi(X - 1, 0), xp = clss_mini(X + 1, W - 1);
    const int ym = clss_maxi(Y - 1, 0), yp = clss_mini(Y + 1, H - 1);
    const long r0 = (long)ym * W, r1 = (long)Y * W, r2 = (long)yp * W;
    float alpha = 0.0f;
    if (learned) {
#if NSRD_ENCODE8
        alpha = alpha8[(long)sub * np_ + o];        /* nsrd_alpha's sigmoid */
#else
        const float z = LD(y, (3 * s * s + sub) * np_ + o);
        alpha = 1.0f / (1.0f + exp(-z));
#endif
    }
    float gb[3] = {0.0f, 0.0f, 0.0f};
    if (guided)
        guided_base(state, albedo, albedo_hr, h, w, Q, bu, bv, demod, eps, gb);
    for (int c = 0; c < 3; ++c) {
#define AHR(r, x) fin(albedo_hr[3 * ((r) + (x)) + c], 0.0f)
        const float a0 = 0.25f * AHR(r0, xm) + 0.5f * AHR(r0, X) + 0.25f * AHR(r0, xp);
        const float a1 = 0.25f * AHR(r1, xm) + 0.5f * AHR(r1, X) + 0.25f * AHR(r1, xp);
        const float a2 = 0.25f * AHR(r2, xm) + 0.5f * AHR(r2, X) + 0.25f * AHR(r2, xp);
#undef AHR
        const float a = 0.25f * a0 + 0.5f * a1 + 0.25f * a2;
        float base = gb[c];
        if (!guided) {      /* the bilinear base: its taps are read only when used */
            __global const float *q = state + c * h * w;
            const float top = q[c0 * w + b0] * (1.0f - fb) + q[c0 * w + b1] * fb;
            const float bot = q[c1 * w + b0] * (1.0f - fb) + q[c1 * w + b1] * fb;
            base = top * (1.0f - fc) + bot * fc;
        }
        const float l = clss_clampf(LD(y, (c * s * s + sub) * np_ + o) + base, 0.0f, 1.0f);
        hist[c * P + Q] = l;
        float m = material(a, demod, eps);
        if (learned)
            m = alpha * material(fin(albedo_hr[3 * Q + c], 0.0f), demod, eps) + (1.0f - alpha) * m;
        out[3 * Q + c] = m;     /* nsrd_decode multiplies in the decoded lighting */
    }
}

/* -DNSRD_GUIDED8=1 (fast path nsrd.guided8): guided_base on the 8 lanes of nsrd_finish8 at
 * once, its weight's exp on pq.h's plain-arithmetic exp2 (pq_exp2q8): lane by lane, the
 * scalar function made 16 out-of-line exp calls an output pixel, 280 of the 325 ms of the
 * shipped x2 weights' output stage at 1080p. The same operations in the same order but
 * for the exp (within the frame step's tolerance of the library's, not bit-identical).
 * bu: the lanes' render-resolution x (clamped to [0, w - 1], so truncation is floor);
 * Qi: their output pixels. */
#ifndef NSRD_GUIDED8
#define NSRD_GUIDED8 0
#endif
#if NSRD_GUIDED8
static void guided_base8(__global const float *state, __global const float *albedo,
                         __global const float *albedo_hr, int h, int w, int8 Qi,
                         float8 bu, float bv, int demod, float eps, float8 *out)
{
    const int8 b0 = CLSS_CVT8(bu, int8);
    const int c0 = (int)bv;
    const long hw = (long)h * w;
    float8 mp[3], acc[3] = {(float8)(0.0f), (float8)(0.0f), (float8)(0.0f)}, ws = (float8)(0.0f);
    for (int c = 0; c < 3; ++c)
        mp[c] = material8(fin8(CLSS_GATHER8(albedo_hr + c, 3 * Qi), 0.0f), demod, eps);
    for (int dy = -1; dy <= 2; ++dy) {
        const int ty = c0 + dy;
        const float dv = bv - (float)ty;
        const float ty_ = 1.0f - (dv < 0.0f ? -dv : dv) * 0.5f, wy = ty_ > 0.0f ? ty_ : 0.0f;
        const int row = clss_clampi(ty, 0, h - 1) * w;
        for (int dx = -1; dx <= 2; ++dx) {
            const int8 tx = b0 + dx;
            const float8 du = bu - CLSS_CVT8(tx, float8);
            const float8 tx_ = 1.0f - (du < 0.0f ? -du : du) * 0.5f;
            const float8 wx = tx_ > 0.0f ? tx_ : (float8)(0.0f);
            const int8 q = (int8)(row) + (tx < 0 ? (int8)(0) : (tx > w - 1 ? (int8)(w - 1) : tx));
            float8 d2 = (float8)(0.0f);
            for (int c = 0; c < 3; ++c) {
                const float8 d = material8(fin8(CLSS_GATHER8(albedo + c, 3 * q), 0.0f), demod, eps) - mp[c];
                d2 += d * d;
            }
            const float8 wt = wy * wx * (pq_exp2q8(-d2 * NSRD_GUIDE_INV_SIG2 * 1.44269504088896341f)
                                         + NSRD_GUIDE_FLOOR);
            for (int c = 0; c < 3; ++c)
                acc[c] += wt * CLSS_GATHER8(state + c * hw, q);
            ws += wt;
        }
    }
    for (int c = 0; c < 3; ++c)
        out[c] = acc[c] / ws;
}
#endif

/** nsrd_finish and nsrd_decode for 8 output pixels of a row (NSRD_ENCODE8): the same
 *  operations on float8 lanes, bit-identical to the two kernels; out gets the material times
 *  the decoded lighting at once. Arguments as nsrd_finish, and nsrd_decode's inv_pq_scale.
 *  NDRange: (ceil(W / 8), H). */
__kernel void nsrd_finish8(__global const T *y, __global const float *state,
                           __global const float *albedo_hr, __global float *hist,
                           __global float *out, int h, int w, int H, int W, int hp, int wp, int s_,
                           float jx, float jy, int demod, float eps,
                           int learned, __global const float *alpha8, float inv_pq_scale,
                           __global const float *albedo, int guided)
{
    const int s = SCALE_OR(s_);
    const int X0 = get_global_id(0) * 8, Y = get_global_id(1);
    if (X0 >= W || Y >= H) return;
    const int n = min(8, W - X0);
    const float fs = (float)s;
    const int8 Xi = (int8)(X0) + (int8)(0, 1, 2, 3, 4, 5, 6, 7);
    const float8 Xf = CLSS_CVT8(Xi, float8);
    const RenderAxis8 ax = render_axis8((Xf + 0.5f) / fs - 0.5f - jx, w);
    const int8 b0 = ax.i0, b1 = ax.i1;
    const float8 fb = ax.f;
    const float bv = clss_clampf(((float)Y + 0.5f) / fs - 0.5f - jy, 0.0f, (float)(h - 1));
    const int c0 = clss_floori(bv);
    const int c1 = clss_mini(c0 + 1, h - 1);
    const float fc = bv - (float)c0;
    const long np_ = (long)hp * wp, P = (long)H * W;
    /* lanes past the row's end repeat its last pixel (computed, not stored) */
    const int8 Xc = Xi < W - 1 ? Xi : (int8)(W - 1);
    const long8 o = (long8)((long)(Y / s) * wp) + CLSS_CVT8(Xc / s, long8);
    const long8 sub = (long8)((Y % s) * s) + CLSS_CVT8(Xc % s, long8);
    const int8 xm = Xc - 1 > 0 ? Xc - 1 : (int8)(0), xp = Xc + 1 < W - 1 ? Xc + 1 : (int8)(W - 1);
    const int ym = clss_maxi(Y - 1, 0), yp = clss_mini(Y + 1, H - 1);
    const long r0 = (long)ym * W, r1 = (long)Y * W, r2 = (long)yp * W;
    const long8 lxm = CLSS_CVT8(xm, long8), lxc = CLSS_CVT8(Xc, long8), lxp = CLSS_CVT8(xp, long8);
    float8 alpha = (float8)(0.0f);
    if (learned)
        alpha = CLSS_GATHER8(alpha8, sub * np_ + o);
    const long8 s00 = (long8)((long)c0 * w) + CLSS_CVT8(b0, long8);
    const long8 s01 = (long8)((long)c0 * w) + CLSS_CVT8(b1, long8);
    const long8 s10 = (long8)((long)c1 * w) + CLSS_CVT8(b0, long8);
    const long8 s11 = (long8)((long)c1 * w) + CLSS_CVT8(b1, long8);
    float ls[3][8], ms[3][8], gb[3][8];
    if (guided) {
#if NSRD_GUIDED8
        const float8 bu8 = (CLSS_CVT8(Xc, float8) + 0.5f) / fs - 0.5f - jx;
        float8 g8[3];
        guided_base8(state, albedo, albedo_hr, h, w, (int8)(Y * W) + Xc,
                     pq_clamp8(bu8, 0.0f, (float)(w - 1)),
                     bv, demod, eps, g8);
        for (int c = 0; c < 3; ++c)
            PST8(gb[c], g8[c]);
#else
        /* lane by lane, the scalar kernel's function: bit-identical to it */
        for (int k = 0; k < 8; ++k) {
            const int Xk = clss_mini(X0 + k, W - 1);
            const float bu = clss_clampf(((float)Xk + 0.5f) / fs - 0.5f - jx, 0.0f, (float)(w - 1));
            float g3[3];
            guided_base(state, albedo, albedo_hr, h, w, (long)Y * W + Xk, bu, bv, demod, eps, g3);
            for (int c = 0; c < 3; ++c)
                gb[c][k] = g3[c];
        }
#endif
    }
    for (int c = 0; c < 3; ++c) {
        __global const float *ac = albedo_hr + c;
#define AHR8(r, x) fin8(CLSS_GATHER8(ac, 3 * ((long8)(r) + (x))), 0.0f)
        const float8 a0 = 0.25f * AHR8(r0, lxm) + 0.5f * AHR8(r0, lxc) + 0.25f * AHR8(r0, lxp);
        const float8 a1 = 0.25f * AHR8(r1, lxm) + 0.5f * AHR8(r1, lxc) + 0.25f * AHR8(r1, lxp);
        const float8 a2 = 0.25f * AHR8(r2, lxm) + 0.5f * AHR8(r2, lxc) + 0.25f * AHR8(r2, lxp);
        const float8 a = 0.25f * a0 + 0.5f * a1 + 0.25f * a2;
        float8 base;
        if (guided) {
            base = PLD8(gb[c]);
        } else {
            __global const float *q = state + c * h * w;
            const float8 top = CLSS_GATHER8(q, s00) * (1.0f - fb) + CLSS_GATHER8(q, s01) * fb;
            const float8 bot = CLSS_GATHER8(q, s10) * (1.0f - fb) + CLSS_GATHER8(q, s11) * fb;
            base = top * (1.0f - fc) + bot * fc;
        }
        const long8 yi = ((long8)(c * s * s) + sub) * np_ + o;
        const float8 yv = (float8)(LD(y, yi.s0), LD(y, yi.s1), LD(y, yi.s2), LD(y, yi.s3),
                                   LD(y, yi.s4), LD(y, yi.s5), LD(y, yi.s6), LD(y, yi.s7));
        float8 l = yv + base;
        l = l > 0.0f ? (l < 1.0f ? l : (float8)(1.0f)) : (float8)(0.0f);
        float8 m = material8(a, demod, eps);
        if (learned) {
            const float8 pa = AHR8(r1, lxc);
            const float8 mp = material8(pa, demod, eps);
            m = alpha * mp + (1.0f - alpha) * m;
        }
#undef AHR8
        PST8(ls[c], l);
        PST8(ms[c], m * pq_decode8(l, inv_pq_scale));
    }
    for (int k = 0; k < n; ++k) {
        const long Q = (long)Y * W + X0 + k;
        for (int c = 0; c < 3; ++c) {
            hist[c * P + Q] = ls[c][k];
            out[3 * Q + c] = ms[c][k];
        }
    }
}

/** The output: the material nsrd_finish left in out times the decoded lighting, 8 pixels
 *  (in row-major order) per work-item so that the PQ decode runs on float8.
 *  @param[in]  hist   [3,H,W] float32: the output lighting (PQ)
 *  @param[in,out] out [H,W,3] float32: the material in, linear colour times the exposure out
 *  @param[in]  P      H * W
 *  @param[in]  inv_pq_scale 10000 / nits, times the exposure
 *  NDRange: (ceil(P / 8)). */
__kernel void nsrd_decode(__global const float *hist, __global float *out, int P,
                          float inv_pq_scale)
{
    const int Q0 = get_global_id(0) * 8;
    if (Q0 >= P) return;
    const int n = min(8, P - Q0);
    for (int c = 0; c < 3; ++c) {
        __global const float *q = hist + (long)c * P + Q0;
        float8 l;
        if (n == 8) {
            l = XLD8(q);
        } else {
            float t[8];
            for (int k = 0; k < 8; ++k)
                t[k] = k < n ? q[k] : 0.0f;
            l = PLD8(t);
        }
        float d[8];
        PST8(d, pq_decode8(l, inv_pq_scale));
        for (int k = 0; k < n; ++k)
            out[3 * (long)(Q0 + k) + c] *= d[k];
    }
}

/** The rules' base (networks.OUT_BASES "rules"): clss-rules' PQ colour of this frame (its
 *  history's channels 0-2), pixel-unshuffled into prev's channels off.. as nsrd_prev
 *  unshuffles the previous output (torch order: off + c s^2 + (Y % s) s + X % s).
 *  @param[in]  rules  [16,H,W] T clss-rules' history (PQ colour in channels 0-2)
 *  @param[out] prev   [6s^2,hp,wp] T; the padding is left as it is (zeroed once)
 *  NDRange: (W, H). */
__kernel void nsrd_rules_in(__global const T *rules, __global T *prev, int H, int W, int hp,
                            int wp, int s_, int off)
{
    const int s = SCALE_OR(s_);
    const int X = get_global_id(0), Y = get_global_id(1);
    if (X >= W || Y >= H) return;
    const long P = (long)H * W, Q = (long)Y * W + X, np_ = (long)hp * wp;
    const long o = (long)(Y / s) * wp + X / s;
    const int sub = (Y % s) * s + X % s;
    for (int c = 0; c < 3; ++c)
        ST(prev, (off + c * s * s + sub) * np_ + o, LD(rules, c * P + Q));
}

/** The output: the rules' moved towards NSRD's by clamp(mix, 0, 1), the mix sub-pixel (its
 *  s^2 channels shuffled as the lighting's are); mix = 0 leaves the rules' output bit for
 *  bit. NSRD's own history is not touched.
 *  @param[in]     rules  [H,W,3] float32 clss-rules' output (linear x exposure)
 *  @param[in]     mix    [s^2,hp,wp] T the network's mix head (linear)
 *  @param[in,out] out    [H,W,3] float32 NSRD's output in, the step's out
 *  NDRange: (W, H). */
__kernel void nsrd_rules_mix(__global const float *rules, __global const T *mix,
                             __global float *out, int H, int W, int hp, int wp, int s_)
{
    const int s = SCALE_OR(s_);
    const int X = get_global_id(0), Y = get_global_id(1);
    if (X >= W || Y >= H) return;
    const long Q = (long)Y * W + X, np_ = (long)hp * wp;
    const long o = (long)(Y / s) * wp + X / s;
    const int sub = (Y % s) * s + X % s;
    const float m = clss_clampf((float)LD(mix, sub * np_ + o), 0.0f, 1.0f);
    for (int c = 0; c < 3; ++c) {
        const float r = rules[3 * Q + c];
        out[3 * Q + c] = r + m * (out[3 * Q + c] - r);
    }
}
