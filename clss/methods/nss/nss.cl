/* NSS's frame step around its network (Arm Neural Super Sampling; the room
 * clss/methods/nss/, whose ONNX twin oracle.py states the same formulas as graph nodes
 * and whose torch twin is weights_tools/methods/nss/twin.py). 2x only.
 *
 *   nss_inputs        render resolution: the caller's frame to internal planes: colour
 *                     [3,h,w] (/ exposure, finite, clamped to [0, COLOR_MAX]), depth [h,w]
 *                     (reversed-Z), motion [2,h,w] (render pixels, scaled)
 *   (scatter_depth)   kernels/scatter.cl: each pixel's depth pushed to the bilinear taps of
 *                     p + motion in the previous frame with atomic max (reversed-Z: the
 *                     nearest; the buffer is cleared to the far plane) -- or, portable,
 *   nss_depth_gather  the same reconstruction by gathering: each previous-frame pixel looks
 *                     for the current pixels whose reprojection reaches it within a
 *                     (2R+1)^2 window around it minus its own motion (no atomics,
 *                     deterministic; equal to the scatter wherever motion varies by less
 *                     than R pixels around a contributor)
 *   nss_pre           padded render resolution (hp, wp multiples of 8; the padding repeats
 *                     the edge): disocclusion from the reconstructed depth, the previous
 *                     output warped (bilinear) and Karis tonemapped, the jittered colour
 *                     tonemapped, the previous temporal parameters warped (the feedback),
 *                     the time-filtered luma derivative: the network's 12 channels; the
 *                     derivative state for the next frame
 *   nss_post          output resolution: the kernel-prediction filter of the jittered
 *                     colour (jitter-aware K x K taps, networks.post_taps), its first and
 *                     second moments; the previous output warped Catmull-Rom; the history
 *                     clamped to the neighbourhood (gamma) and rectified (theta); the new
 *                     sample accumulated with alpha in the Karis-tonemapped domain; the
 *                     output and the next history
 *
 * keep = 0 on a reset: no history is read (the disocclusion is 1 everywhere).
 * Constants (-D): KPN (taps per side), and networks.py's, passed by frame.py.
 */
#include "common.h"

#pragma OPENCL FP_CONTRACT OFF

#include "warp_taps.h"

#ifndef KPN
#define KPN 4
#endif
/* Defaults: networks.py's values (frame.py passes them as -D; tests/test_method_nss.py checks
 * these equal them), so the source also builds on its own, as a porter builds it. */
#ifndef COLOR_MAX
#define COLOR_MAX 65504.0f
#endif
#ifndef DEPTH_TOL
#define DEPTH_TOL 0.05f
#endif
#ifndef DEPTH_FLOOR
#define DEPTH_FLOOR 1e-06f
#endif
#ifndef GATHER_R
#define GATHER_R 2
#endif
#ifndef D_MIN
#define D_MIN 0.05f
#endif
#ifndef D_MAX
#define D_MAX 0.3f
#endif
#ifndef D_ALPHA
#define D_ALPHA 0.1f
#endif
#ifndef LUMA_R
#define LUMA_R 0.2126f
#endif
#ifndef LUMA_G
#define LUMA_G 0.7152f
#endif
#ifndef LUMA_B
#define LUMA_B 0.0722f
#endif
#ifndef KPN_EPS
#define KPN_EPS 1e-07f
#endif
#ifndef CLAMP_EPS
#define CLAMP_EPS 1e-07f
#endif
#ifndef TM_MAX
#define TM_MAX 0.9999990463256836f
#endif
#ifndef ALPHA_LO
#define ALPHA_LO 0.05f
#endif
#ifndef ALPHA_HI
#define ALPHA_HI 0.4f
#endif
#ifndef GAMMA_SCALE
#define GAMMA_SCALE 2.0f
#endif

static float fin(float v, float fill)
{
    return isfinite(v) ? v : fill;
}

/* Karis tonemap x / (1 + max(r, g, b)) of one pixel's three channels, in place. */
static void karis(float *c)
{
    const float s = 1.0f / (1.0f + fmax(fmax(c[0], c[1]), c[2]));
    c[0] *= s;
    c[1] *= s;
    c[2] *= s;
}

/** @param[in]  color, depth, motion  the caller's frame (image layout, float32)
 *  @param[out] col  [3,h,w] float32 colour / exposure in [0, COLOR_MAX]
 *  @param[out] dz   [h,w] float32 reversed-Z depth
 *  @param[out] mv   [2,h,w] float32 motion (render pixels, previous = p + motion)
 *  NDRange: (w, h). */
__kernel void nss_inputs(__global const float *color, __global const float *depth,
                         __global const float *motion, __global float *col, __global float *dz,
                         __global float *mv, int w, int h, int depth_inverted, float msx,
                         float msy, float inv_exposure)
{
    const int x = get_global_id(0), y = get_global_id(1);
    if (x >= w || y >= h) return;
    const int p = y * w + x, plane = w * h;
    for (int c = 0; c < 3; ++c)
        col[c * plane + p] = clamp(fin(color[3 * p + c], 0.0f) * inv_exposure, 0.0f, COLOR_MAX);
    const float d = fin(depth[p], depth_inverted ? 0.0f : 1.0f);
    dz[p] = depth_inverted ? d : 1.0f - d;
    mv[p] = fin(motion[2 * p], 0.0f) * msx;
    mv[plane + p] = fin(motion[2 * p + 1], 0.0f) * msy;
}

/** The portable depth reconstruction (no atomics): recon[t] = the largest reversed-Z depth
 *  among the current pixels q within GATHER_R of round(t - motion(t)) one of whose bilinear
 *  taps at q + motion(q) is t with weight > wmin (scatter_depth's rule); 0 (far) if none.
 *  @param[in]  dz, mv  nss_inputs' planes
 *  @param[out] recon   [h,w] uint: float bits, as scatter_depth writes them
 *  NDRange: (w, h). */
__kernel void nss_depth_gather(__global const float *dz, __global const float *mv,
                               __global uint *recon, int w, int h, float wmin)
{
    const int x = get_global_id(0), y = get_global_id(1);
    if (x >= w || y >= h) return;
    const int plane = w * h;
    const int gx = (int)floor((float)x - mv[y * w + x] + 0.5f);
    const int gy = (int)floor((float)y - mv[plane + y * w + x] + 0.5f);
    float best = 0.0f;
    for (int dy = -GATHER_R; dy <= GATHER_R; ++dy)
        for (int dx = -GATHER_R; dx <= GATHER_R; ++dx) {
            const int qx = gx + dx, qy = gy + dy;
            if (qx < 0 || qx >= w || qy < 0 || qy >= h) continue;
            const int q = qy * w + qx;
            const float d = dz[q];
            if (!(d >= 0.0f) || d <= best) continue;
            const float px = (float)qx + mv[q], py = (float)qy + mv[plane + q];
            const float bx = floor(px), by = floor(py);
            if (!(bx >= -1.0f && bx < (float)w && by >= -1.0f && by < (float)h)) continue;
            const int a = x - (int)bx, b = y - (int)by;
            if (a < 0 || a > 1 || b < 0 || b > 1) continue;
            const float fx = px - bx, fy = py - by;
            const float wk = (a ? fx : 1.0f - fx) * (b ? fy : 1.0f - fy);
            if (wk > wmin) best = d;
        }
    recon[y * w + x] = best == 0.0f ? 0u : as_uint(best);
}

/** @param[in]  col, dz, mv  nss_inputs' planes
 *  @param[in]  recon      [h,w] uint the reconstructed previous depth (float bits)
 *  @param[in]  hist       [3,H,W] float32 the previous output (linear / exposure)
 *  @param[in]  tp_prev    [4,hp,wp] T the previous frame's temporal parameters
 *  @param[in]  deriv_old  [2,h,w] float32 the previous (derivative, luma)
 *  @param[out] deriv_new  [2,h,w] float32
 *  @param[out] x          [12,hp,wp] T the network's input
 *  NDRange: (wp, hp). */
__kernel void nss_pre(__global const float *col, __global const float *dz,
                      __global const float *mv, __global const uint *recon,
                      __global const float *hist, __global const T *tp_prev,
                      __global const float *deriv_old, __global float *deriv_new, __global T *x,
                      int w, int h, int wp, int hp, float keep)
{
    const int gx = get_global_id(0), gy = get_global_id(1);
    if (gx >= wp || gy >= hp) return;
    const int px = min(gx, w - 1), py = min(gy, h - 1);
    const int p = py * w + px, plane = w * h, W = 2 * w, H = 2 * h;
    const long np_ = (long)hp * wp, q = (long)gy * wp + gx;
    const float d = dz[p], mx = mv[p], my = mv[plane + p];
    const float xs = (float)px + mx, ys = (float)py + my;
    const WarpTaps t = warp_taps(xs, ys, w, h);
    /* disocclusion */
    const float dr = as_float(recon[t.cy0 * w + t.cx0]) * t.w00 + as_float(recon[t.cy0 * w + t.cx1]) * t.w10
                   + as_float(recon[t.cy1 * w + t.cx0]) * t.w01 + as_float(recon[t.cy1 * w + t.cx1]) * t.w11;
    const float rel = fmax(dr - d, 0.0f) / (DEPTH_TOL * fmax(d, dr) + DEPTH_FLOOR);
    const float ins = (xs >= -0.5f && xs <= (float)w - 0.5f && ys >= -0.5f && ys <= (float)h - 0.5f)
                      ? 1.0f : 0.0f;
    const float dis = 1.0f - (1.0f - clamp(rel - 1.0f, 0.0f, 1.0f)) * ins * keep;
    /* the previous output at this pixel's centre, moved (output pixels) */
    const WarpTaps th = warp_taps((float)(2 * px) + 0.5f + 2.0f * mx,
                                  (float)(2 * py) + 0.5f + 2.0f * my, W, H);
    float hc[3], cc[3];
    for (int c = 0; c < 3; ++c) {
        __global const float *o = hist + (long)c * H * W;
        const float v = o[(long)th.cy0 * W + th.cx0] * th.w00 + o[(long)th.cy0 * W + th.cx1] * th.w10
                      + o[(long)th.cy1 * W + th.cx0] * th.w01 + o[(long)th.cy1 * W + th.cx1] * th.w11;
        hc[c] = v * keep;
        cc[c] = col[c * plane + p];
    }
    karis(hc);
    karis(cc);
    for (int c = 0; c < 3; ++c) {
        ST(x, c * np_ + q, hc[c]);
        ST(x, (3 + c) * np_ + q, cc[c]);
    }
    ST(x, 6 * np_ + q, dis);
    /* the feedback: the previous temporal parameters warped (render region, zero outside) */
    const long a00 = (long)t.cy0 * wp + t.cx0, a10 = (long)t.cy0 * wp + t.cx1;
    const long a01 = (long)t.cy1 * wp + t.cx0, a11 = (long)t.cy1 * wp + t.cx1;
    for (int c = 0; c < 4; ++c) {
        const long b = c * np_;
        const float v = LD(tp_prev, b + a00) * t.w00 + LD(tp_prev, b + a10) * t.w10
                      + LD(tp_prev, b + a01) * t.w01 + LD(tp_prev, b + a11) * t.w11;
        ST(x, (7 + c) * np_ + q, v * keep * (1.0f - dis));
    }
    /* the time-filtered luma derivative */
    float s[2];
    for (int c = 0; c < 2; ++c) {
        __global const float *o = deriv_old + c * plane;
        s[c] = (o[t.cy0 * w + t.cx0] * t.w00 + o[t.cy0 * w + t.cx1] * t.w10
                + o[t.cy1 * w + t.cx0] * t.w01 + o[t.cy1 * w + t.cx1] * t.w11) * keep;
    }
    const float l = LUMA_R * cc[0] + LUMA_G * cc[1] + LUMA_B * cc[2];
    const float tt = clamp((fabs(l - s[1]) - D_MIN) / (D_MAX - D_MIN), 0.0f, 1.0f);
    const float rate = D_ALPHA * (1.0f - 0.9f * fmin(s[0] / D_MAX, 1.0f));
    const float der = (s[0] + rate * (tt * sqrt(tt) - s[0])) * (1.0f - dis);
    ST(x, 11 * np_ + q, der);
    if (gx < w && gy < h) {
        deriv_new[p] = der;
        deriv_new[plane + p] = l;
    }
}

/* A render-resolution plane p [hp,wp] (row pitch wp) at output pixel (X, Y)'s centre:
 * bilinear, edge-clamped to the render region (the temporal parameters, the mix). */
static float at_output(__global const T *p, int X, int Y, int w, int h, int wp)
{
    const float a = clamp(((float)X + 0.5f) / 2.0f - 0.5f, 0.0f, (float)(w - 1));
    const float b = clamp(((float)Y + 0.5f) / 2.0f - 0.5f, 0.0f, (float)(h - 1));
    const int a0 = (int)floor(a), b0 = (int)floor(b);
    const int a1 = min(a0 + 1, w - 1), b1 = min(b0 + 1, h - 1);
    const float fa = a - (float)a0, fb = b - (float)b0;
    const float top = LD(p, (long)b0 * wp + a0) * (1.0f - fa) + LD(p, (long)b0 * wp + a1) * fa;
    const float bot = LD(p, (long)b1 * wp + a0) * (1.0f - fa) + LD(p, (long)b1 * wp + a1) * fa;
    return top * (1.0f - fb) + bot * fb;
}

/* Catmull-Rom weights of the taps at -1, 0, 1, 2 around fraction f. */
static float4 catmull_rom(float f)
{
    const float f2 = f * f, f3 = f2 * f;
    return (float4)(-0.5f * f3 + f2 - 0.5f * f, 1.5f * f3 - 2.5f * f2 + 1.0f,
                    -1.5f * f3 + 2.0f * f2 + 0.5f * f, 0.5f * f3 - 0.5f * f2);
}

/** @param[in]  col, mv    nss_inputs' planes
 *  @param[in]  kpn        [K*K,hp/4,wp/4] T the kernel weights (tap ty*K + tx)
 *  @param[in]  tp         [4,hp,wp] T this frame's temporal parameters
 *  @param[in]  hist_old   [3,H,W] float32 the previous output (linear / exposure)
 *  @param[out] hist_new   [3,H,W] float32 this output (linear / exposure)
 *  @param[out] out        [H,W,3] float32 this output times the exposure
 *  NDRange: (W, H); W = 2w, H = 2h. */
__kernel void nss_post(__global const float *col, __global const float *mv,
                       __global const T *kpn, __global const T *tp,
                       __global const float *hist_old, __global float *hist_new,
                       __global float *out, int w, int h, int wp, int hp, float jx, float jy,
                       float keep, float exposure)
{
    const int X = get_global_id(0), Y = get_global_id(1);
    const int W = 2 * w, H = 2 * h;
    if (X >= W || Y >= H) return;
    const int plane = w * h;
    const int R = KPN / 2 - 1;
    /* the taps (networks.post_taps) */
    const float u = ((float)X + 0.5f) / 2.0f - 0.5f - jx, v = ((float)Y + 0.5f) / 2.0f - 0.5f - jy;
    const float fu = floor(u), fv = floor(v);
    float tx[KPN], ty[KPN];
    for (int k = 0; k < KPN; ++k) {
        tx[k] = fmax((float)(KPN / 2) - fabs((fu + (float)(k - R)) - u), 0.0f);
        ty[k] = fmax((float)(KPN / 2) - fabs((fv + (float)(k - R)) - v), 0.0f);
    }
    const float cu = floor(u + 0.5f), cv = floor(v + 0.5f);
    const int valid = floor((cu + 0.5f + jx) * 2.0f) == (float)X && floor((cv + 0.5f + jy) * 2.0f) == (float)Y
                      && cu >= 0.0f && cu < (float)w && cv >= 0.0f && cv < (float)h;
    const int cx = clamp((int)cu, 0, w - 1), cy = clamp((int)cv, 0, h - 1);
    const int kw = wp / 4, kh = hp / 4;
    const long kplane = (long)kw * kh, kq = (long)(cy / 4) * kw + cx / 4;
    const int x0 = (int)fu - R, y0 = (int)fv - R;
    float m1[3] = {0.0f, 0.0f, 0.0f}, m2[3] = {0.0f, 0.0f, 0.0f}, ws = 0.0f;
    for (int j = 0; j < KPN; ++j) {
        const int sy = clamp(y0 + j, 0, h - 1);
        for (int i = 0; i < KPN; ++i) {
            const int sx = clamp(x0 + i, 0, w - 1);
            const float wk = fmax(LD(kpn, (j * KPN + i) * kplane + kq), KPN_EPS) * (tx[i] * ty[j]);
            ws += wk;
            for (int c = 0; c < 3; ++c) {
                const float a = col[c * plane + sy * w + sx];
                m1[c] += wk * a;
                m2[c] += wk * (a * a);
            }
        }
    }
    /* the temporal parameters at this output pixel */
    const long np_ = (long)hp * wp;
    float pr[3];
    for (int c = 0; c < 3; ++c)
        pr[c] = at_output(tp + c * np_, X, Y, w, h, wp);
    const float ta = pr[0] * pr[0], tb = (1.0f - pr[0]) * (1.0f - pr[0]);
    const float theta = ta / fmax(ta + tb, 1e-6f);
    const float alpha = ALPHA_LO + (ALPHA_HI - ALPHA_LO) * pr[1];
    const float gamma = GAMMA_SCALE * pr[2];
    /* the previous output, Catmull-Rom at this pixel moved (the render pixel's motion) */
    const int rp = (Y / 2) * w + X / 2;
    const float hx = (float)X + 2.0f * mv[rp], hy = (float)Y + 2.0f * mv[plane + rp];
    const float ons = (hx >= -0.5f && hx <= (float)W - 0.5f && hy >= -0.5f && hy <= (float)H - 0.5f)
                      ? 1.0f : 0.0f;
    const float fhx = floor(hx), fhy = floor(hy);
    const float4 wx = catmull_rom(hx - fhx), wy = catmull_rom(hy - fhy);
    const float wxs[4] = {wx.s0, wx.s1, wx.s2, wx.s3}, wys[4] = {wy.s0, wy.s1, wy.s2, wy.s3};
    /* a motion far off screen: clamp before the int conversion (the taps clamp anyway) */
    const int hx0 = (int)clamp(fhx, -4.0f, (float)W + 4.0f) - 1;
    const int hy0 = (int)clamp(fhy, -4.0f, (float)H + 4.0f) - 1;
    float hv[3] = {0.0f, 0.0f, 0.0f};
    for (int j = 0; j < 4; ++j) {
        const long row = (long)clamp(hy0 + j, 0, H - 1) * W;
        float r[3] = {0.0f, 0.0f, 0.0f};
        for (int i = 0; i < 4; ++i) {
            const long o = row + clamp(hx0 + i, 0, W - 1);
            for (int c = 0; c < 3; ++c)
                r[c] += wxs[i] * hist_old[(long)c * H * W + o];
        }
        for (int c = 0; c < 3; ++c)
            hv[c] += wys[j] * r[c];
    }
    float rect[3], cen[3];
    const float tk = theta * ons * keep;
    const float ak = alpha * (valid ? 1.0f : 0.0f) * keep;
    for (int c = 0; c < 3; ++c) {
        const float f1 = m1[c] / ws, f2 = m2[c] / ws;
        const float wh = clamp(hv[c], 0.0f, COLOR_MAX);
        const float sg = sqrt(fmax(fabs(f2 - f1 * f1), CLAMP_EPS)) * gamma;
        const float hcl = f1 + (clamp(wh, f1 - sg, f1 + sg) - f1) * keep;
        rect[c] = hcl + (wh - hcl) * tk;
        cen[c] = col[c * plane + cy * w + cx];
    }
    karis(rect);
    karis(cen);
    float acc[3];
    for (int c = 0; c < 3; ++c)
        acc[c] = clamp(rect[c] + (cen[c] - rect[c]) * ak, 0.0f, TM_MAX);
    const float inv = 1.0f / (1.0f - fmax(fmax(acc[0], acc[1]), acc[2]));
    const long P = (long)H * W, Q = (long)Y * W + X;
    for (int c = 0; c < 3; ++c) {
        const float lin = acc[c] * inv;
        hist_new[c * P + Q] = lin;
        out[3 * Q + c] = lin * exposure;
    }
}

/* ---- the rules' base (networks.BASES "rules"; frame.py runs clss-rules' frame step
 * beside these and hands over its output) ---------------------------------------------- */

/** The network's channels IN..IN+2: the rules' output (linear x exposure) / exposure,
 *  averaged over the 2 x 2 output pixels of each render pixel, Karis tonemapped; the
 *  padding repeats the edge (as nss_pre's).
 *  @param[in]  rules  [H,W,3] float32 clss-rules' output of this frame
 *  @param[out] x      [IN+3,hp,wp] T (channels IN..IN+2 written)
 *  NDRange: (wp, hp). */
__kernel void nss_rules_in(__global const float *rules, __global T *x, int w, int h, int wp,
                           int hp, int in_ch, float inv_exposure)
{
    const int gx = get_global_id(0), gy = get_global_id(1);
    if (gx >= wp || gy >= hp) return;
    const int px = min(gx, w - 1), py = min(gy, h - 1), W = 2 * w;
    const long np_ = (long)hp * wp, q = (long)gy * wp + gx;
    const long r0 = ((long)(2 * py) * W + 2 * px) * 3, r1 = r0 + (long)W * 3;
    float c3[3];
    for (int c = 0; c < 3; ++c)
        c3[c] = ((rules[r0 + c] + rules[r0 + 3 + c]) + (rules[r1 + c] + rules[r1 + 3 + c]))
                * 0.25f * inv_exposure;
    karis(c3);
    for (int c = 0; c < 3; ++c)
        ST(x, (in_ch + c) * np_ + q, c3[c]);
}

/** The output: the rules' moved towards NSS's by clamp(mix, 0, 1) at the pixel (bilinear,
 *  as the temporal parameters); mix = 0 leaves the rules' output bit for bit. The next
 *  history is the output / exposure.
 *  @param[in]     rules     [H,W,3] float32 clss-rules' output (linear x exposure)
 *  @param[in]     mix       [hp,wp] T the network's mix head (linear)
 *  @param[in,out] out       [H,W,3] float32 nss_post's output in, the step's out
 *  @param[out]    hist_new  [3,H,W] float32
 *  NDRange: (W, H). */
__kernel void nss_rules_mix(__global const float *rules, __global const T *mix,
                            __global float *out, __global float *hist_new, int w, int h, int wp,
                            float inv_exposure)
{
    const int X = get_global_id(0), Y = get_global_id(1);
    const int W = 2 * w, H = 2 * h;
    if (X >= W || Y >= H) return;
    const float m = clamp(at_output(mix, X, Y, w, h, wp), 0.0f, 1.0f);
    const long P = (long)H * W, Q = (long)Y * W + X;
    for (int c = 0; c < 3; ++c) {
        const float r = rules[3 * Q + c];
        const float o = r + m * (out[3 * Q + c] - r);
        out[3 * Q + c] = o;
        hist_new[c * P + Q] = o * inv_exposure;
    }
}
