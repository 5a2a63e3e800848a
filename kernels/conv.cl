/* conv2d / conv_transpose2d, NCHW, direct (no im2col buffer), float accumulation
 * in fp32 and fp16 storage modes.
 *
 * Each work-item computes a register block of XB = 8*XV contiguous output x
 * positions times CB output channels of one output row: XV*CB A8 accumulators.
 * Per kernel tap it loads XV input vectors and CB weights (scalars, broadcast),
 * so every input load feeds CB multiply-adds and every weight load XB of them.
 *
 * Build options:
 *   -DKH=, -DKW=   kernel height/width (compile time so the tap loops unroll)
 *   -DSX=          conv2d x stride: 1 and 2 load rows as vectors, others gather
 *   -DXV=1|2       A8 vectors along x per work-item (tunable)
 *   -DCB=1..8      output channels per work-item (tunable; the host lowers it
 *                  for groups with few output channels, e.g. depthwise)
 *   -DACT=         fused activation (common.h); alpha is a kernel argument
 *   -DCONV_S2K3=0|1 fast path for SX=2, KW=3, dilation 1 along x (the host
 *                  sets 1 only for such layers): per input row and channel,
 *                  each XB-output block loads 2*XB+1 inputs once (two A8 and a
 *                  scalar per A8 of outputs) and derives the three taps by
 *                  de-interleaving (tap 0 = even lanes, tap 1 = odd lanes,
 *                  tap 2 = even lanes shifted by one plus the scalar), instead
 *                  of three strided two-vector loads; edge blocks load with
 *                  unit stride through ld8_guarded. 0 (the reference): the
 *                  generic per-tap loads (ld8_inside/ld8_guarded with s=2).
 *   -DCONV_DEINTERLEAVE=1 (default) stride-2 rows as two vector loads de-interleaved
 *                  with .even (the fast path); =0 gathers them element by element
 *                  (the portable reference the fast-path self-check compares with)
 *   -DCLSS_CLANG_VECTORS  builtin-free loads (common.h; =0 is their reference)
 *
 * Runtime flags (arg `flags`): bias present; residual added before the
 * activation (ResNet's relu(conv(x) + r)); residual added after it.
 *
 * Edges: a work-item whose input window along x lies wholly inside the row
 * takes the vector path; others (the first/last block of a padded row, the
 * tail block of a width not a multiple of XB) load through `ld8_guarded`,
 * which never reads outside the row. Rows outside the image are skipped.
 * Output channels past the group's end reuse the last valid channel's weights
 * (so no load leaves the weight tensor) and are not stored.
 */
#include "common.h"
#include "d2s_index.h"      /* -DD2S: a DepthToSpace fused into conv2d's store */

#ifndef KH
#define KH 3
#endif
#ifndef KW
#define KW 3
#endif
#ifndef SX
#define SX 1
#endif
#ifndef XV
#define XV 1
#endif
#ifndef CB
#define CB 8
#endif
#ifndef CONV_S2K3
#define CONV_S2K3 0
#endif
#if XV != 1 && XV != 2
#error "XV must be 1 or 2"
#endif
#if CB < 1 || CB > 8
#error "CB must be in 1..8"
#endif

#define XB (8 * XV)
#define KK (KH * KW)

#define F_BIAS 1
#define F_RES_BEFORE 2
#define F_RES_AFTER 4

/* FLD/FLD8/FST/FST8 (builtin-free loads on PoCL) and TW/LDW (float weights in
 * fp16 storage mode): kernels/common.h. */

#ifndef CONV_DEINTERLEAVE
#define CONV_DEINTERLEAVE 1
#endif

#define IMIN(a, b) ((a) < (b) ? (a) : (b))
#define IMAX(a, b) ((a) > (b) ? (a) : (b))

/* Inputs ix + (0..7)*s of a row, zero where outside [0, W), never reading
 * outside it. Vectors wholly inside (most of an edge work-item's loads
 * too) take one vector load; the others go element by element. */
inline A8 ld8_guarded(__global const T *row, int ix, int W, int s)
{
    if (s == 1 && ix >= 0 && ix + 8 <= W)
        return FLD8(row, ix);
    union { A8 v; A e[8]; } u;
    for (int e = 0; e < 8; ++e) {
        const int p = ix + e * s;
        const A t = FLD(row, IMIN(IMAX(p, 0), W - 1));
        u.e[e] = (p >= 0 && p < W) ? t : A_ZERO;
    }
    return u.v;
}

/* Inputs ix, ix+s, ..., ix+7s of a row known to be in bounds
 * (for s == 2: ix..ix+15 in bounds). s is a literal at every call site. */
inline A8 ld8_inside(__global const T *row, int ix, int s)
{
    if (s == 1)
        return FLD8(row, ix);
    if (s == 2 && CONV_DEINTERLEAVE) {
        const A8 a = FLD8(row, ix), b = FLD8(row, ix + 8);
        return (A8)(a.even, b.even);
    }
    return (A8)(FLD(row, ix), FLD(row, ix + s), FLD(row, ix + 2 * s), FLD(row, ix + 3 * s),
                FLD(row, ix + 4 * s), FLD(row, ix + 5 * s), FLD(row, ix + 6 * s), FLD(row, ix + 7 * s));
}

/* relu and leaky_relu as vector selects rather than the fmax/select
 * builtins (calls on PoCL). NaN passes through, as in onnxruntime: the
 * comparisons are false for NaN, so each picks v (fmax(v, 0) would give 0). */
#if ACT == ACT_RELU
#define ACT8(v, alpha) ((v) < (A8)A_ZERO ? (A8)A_ZERO : (v))
#elif ACT == ACT_LEAKY_RELU
#define ACT8(v, alpha) ((v) < (A8)A_ZERO ? (v) * (A)(alpha) : (v))
#else
#define ACT8 APPLY_ACT
#endif

/* Bias, residual and activation, in the order the flags ask for. */
inline A8 epilogue(A8 v, A b, A8 r, int flags, float alpha)
{
    v += b;
    if (flags & F_RES_BEFORE)
        v += r;
    v = ACT8(v, alpha);
    if (flags & F_RES_AFTER)
        v += r;
    return v;
}

/* Load/store n <= 8 outputs spaced os apart; the full contiguous case is one
 * vector access, the rest go element by element and stay inside the tensor. */
inline A8 ld_out8(__global const T *p, long o, int os, int n)
{
    if (os == 1 && n == 8)
        return FLD8(p, o);
    union { A8 v; A e[8]; } u;
    for (int e = 0; e < 8; ++e)
        u.e[e] = FLD(p, o + (long)IMIN(e, n - 1) * os);
    return u.v;
}

inline void st_out8(__global T *p, long o, int os, int n, A8 v)
{
    if (os == 1 && n == 8) {
        FST8(p, o, v);
        return;
    }
    union { A8 v; A e[8]; } u;
    u.v = v;
    for (int e = 0; e < n; ++e)
        FST(p, o + (long)e * os, u.e[e]);
}

/* One kernel tap for all CB channels: XV input vectors times CB weights
 * (a*b + c: OpenCL contracts it to an FMA where the device has one). */
#define TAP(LOAD, woff)                                                        \
    {                                                                          \
        A8 xv[XV];                                                             \
        for (int v_ = 0; v_ < XV; ++v_)                                        \
            xv[v_] = LOAD(v_);                                                 \
        _Pragma("unroll") for (int j_ = 0; j_ < CB; ++j_) {                    \
            const A wj = LDW(wc, wo[j_] + (woff));                             \
            _Pragma("unroll") for (int v_ = 0; v_ < XV; ++v_)                  \
                acc[j_][v_] += wj * xv[v_];                                    \
        }                                                                      \
    }

/* Store the block: CB channels (nco valid) x XB positions (nx valid) spaced os, the first
 * of channel co and vector v at element INDEX (an expression of co and v). */
#define STORE_AT(INDEX, OS, NX)                                                \
    for (int j = 0; j < CB; ++j) {                                             \
        if (j >= nco)                                                          \
            break;                                                             \
        const int co = co0 + j;                                                \
        const A b = (flags & F_BIAS) ? FLD(bias, co) : A_ZERO;                 \
        for (int v = 0; v < XV; ++v) {                                         \
            const int n_ = IMIN(8, (NX) - 8 * v);                              \
            if (n_ <= 0)                                                       \
                break;                                                         \
            const long o = (INDEX);                                            \
            A8 r = (A8)A_ZERO;                                                 \
            if (flags & (F_RES_BEFORE | F_RES_AFTER))                          \
                r = ld_out8(res, o, (OS), n_);                                 \
            st_out8(y, o, (OS), n_, epilogue(acc[j][v], b, r, flags, alpha));  \
        }                                                                      \
    }
#define STORE_BLOCK(OUT_OFF, OS, NX)                                           \
    STORE_AT((OUT_OFF) + ((long)co * Ho + oy) * Wo + (long)(8 * v) * (OS), OS, NX)

/* x: [N, Cin, H, W]; w: [Cout, Cin/groups, KH, KW]; y, res: [N, Cout, Ho, Wo].
 * NDRange: (ceil(Wo / XB), Ho, N * groups * ncb) with ncb = ceil((Cout/groups) / CB). */
/** @param[in]  x       [N, Cin, H, W] input
 *  @param[in]  w       weights, [Cout, Cin/groups, KH, KW] (TW: float when fp16 storage converted them)
 *  @param[in]  bias    [Cout] bias (read when flags has 1)
 *  @param[in]  res     [N, Cout, Ho, Wo] residual (read when flags has 2 or 4)
 *  @param[out] y       [N, Cout, Ho, Wo] output
 *  @param[in]  Cin     input channels
 *  @param[in]  H       input height
 *  @param[in]  W       input width
 *  @param[in]  Cout    output channels
 *  @param[in]  Ho      output height
 *  @param[in]  Wo      output width
 *  @param[in]  Cin_g   input channels per group
 *  @param[in]  Cout_g  output channels per group
 *  @param[in]  ncb     output-channel blocks per group, ceil(Cout_g / CB)
 *  @param[in]  groups  groups
 *  @param[in]  sy      stride along y
 *  @param[in]  pt      top pad
 *  @param[in]  pl      left pad
 *  @param[in]  dy      dilation along y
 *  @param[in]  dx      dilation along x
 *  @param[in]  flags   1 bias, 2 residual added before the activation, 4 after it
 *  @param[in]  alpha   the activation's parameter (leaky_relu slope)
 *  @param[in]  nz      the extent of NDRange dimension 2 that is real work
 *  @note -DKH, -DKW: kernel size, -DSX: x stride; -DXV=1|2, -DCB=1..8: the register block (tunable); -DACT: the fused activation
 *  @note -DCONV_S2K3=0|1, -DCONV_DEINTERLEAVE=0|1, -DCLSS_CLANG_VECTORS=0|1: fast paths and their references
 *  @note -DD2S=r, -DD2S_CRD=0|1: a DepthToSpace fused into the store (d2s_index.h); y and res are then the shuffled [N, Cout/r^2, Ho r, Wo r]
 *  @note -DCLSS_FP16 / -DCLSS_FP16_NATIVE: the storage precision (common.h); T and TB follow it
 */
__kernel void conv2d(__global const T *x, __global const TW *w, __global const T *bias,
                     __global const T *res, __global T *y,
                     int Cin, int H, int W, int Cout, int Ho, int Wo,
                     int Cin_g, int Cout_g, int ncb, int groups,
                     int sy, int pt, int pl, int dy, int dx,
                     int flags, float alpha, int nz)
{
    const int xb = get_global_id(0), oy = get_global_id(1), z = get_global_id(2);
    if (xb * XB >= Wo || oy >= Ho || z >= nz)
        return;
    const int cb = z % ncb, g = (z / ncb) % groups, n = z / (ncb * groups);
    const int nco = IMIN(CB, Cout_g - cb * CB);
    const int co0 = g * Cout_g + cb * CB;
    const int Kc = Cin_g * KK;
    int wo[CB];
    for (int j = 0; j < CB; ++j)
        wo[j] = (co0 + IMIN(j, nco - 1)) * Kc;

    const int ox0 = xb * XB, ix0 = ox0 * SX - pl, iy0 = oy * sy - pt;
    const int span = (SX == 2 ? 2 * XB : (XB - 1) * SX + 1) + (KW - 1) * dx;
    const int inside = ix0 >= 0 && ix0 + span <= W;

    A8 acc[CB][XV];
    for (int j = 0; j < CB; ++j)
        for (int v = 0; v < XV; ++v)
            acc[j][v] = (A8)A_ZERO;

    const __global T *xg = x + ((long)n * Cin + (long)g * Cin_g) * H * W;
    const int ky0 = iy0 < 0 ? (-iy0 + dy - 1) / dy : 0;           /* first row inside */
    const int ky1 = IMIN(KH, (H - iy0 + dy - 1) / dy);            /* one past the last */
/* Rows outer, input channels inner: the inner loop runs Cin_g times (long,
 * well predicted) with all KW taps unrolled in its body. */
#define CONV_LOOP(LOAD)                                                        \
    for (int ky = ky0; ky < ky1; ++ky) {                                       \
        const __global T *row = xg + (long)(iy0 + ky * dy) * W;                \
        const __global TW *wc = w + ky * KW;                                   \
        for (int ci = 0; ci < Cin_g; ++ci, row += (long)H * W, wc += KK) {     \
            _Pragma("unroll") for (int kx = 0; kx < KW; ++kx)                  \
                TAP(LOAD, kx)                                                  \
        }                                                                      \
    }
#define LOAD_INSIDE(v_) ld8_inside(row, ix0 + kx * dx + 8 * SX * (v_), SX)
#define LOAD_GUARDED(v_) ld8_guarded(row, ix0 + kx * dx + 8 * SX * (v_), W, SX)
#if SX == 2 && KW == 3 && CONV_S2K3
/* Stride 2, three taps along x, dx == 1 (CONV_S2K3 above): one load of the
 * inputs ix0 + 16v .. ix0 + 16v + 16 per A8 of outputs and input channel. */
#define S2K3_LOOP(LDV, LDS)                                                    \
    for (int ky = ky0; ky < ky1; ++ky) {                                       \
        const __global T *row = xg + (long)(iy0 + ky * dy) * W;                \
        const __global TW *wc = w + ky * KW;                                   \
        for (int ci = 0; ci < Cin_g; ++ci, row += (long)H * W, wc += KK) {     \
            A8 t0[XV], t1[XV], t2[XV];                                         \
            _Pragma("unroll") for (int v_ = 0; v_ < XV; ++v_) {                \
                const int b_ = ix0 + 16 * v_;                                  \
                const A8 a_ = LDV(b_), c_ = LDV(b_ + 8);                       \
                const A e_ = LDS(b_ + 16);                                     \
                t0[v_] = (A8)(a_.even, c_.even);                               \
                t1[v_] = (A8)(a_.odd, c_.odd);                                 \
                t2[v_] = (A8)(a_.s246, c_.even, e_);                           \
            }                                                                  \
            _Pragma("unroll") for (int j_ = 0; j_ < CB; ++j_) {                \
                const A w0 = LDW(wc, wo[j_]), w1 = LDW(wc, wo[j_] + 1),        \
                        w2 = LDW(wc, wo[j_] + 2);                              \
                _Pragma("unroll") for (int v_ = 0; v_ < XV; ++v_) {            \
                    acc[j_][v_] += w0 * t0[v_];                                \
                    acc[j_][v_] += w1 * t1[v_];                                \
                    acc[j_][v_] += w2 * t2[v_];                                \
                }                                                              \
            }                                                                  \
        }                                                                      \
    }
#define S2_LDV_IN(i) FLD8(row, (i))
#define S2_LDS_IN(i) FLD(row, (i))
#define S2_LDV_G(i) ld8_guarded(row, (i), W, 1)
#define S2_LDS_G(i) (((i) >= 0 && (i) < W) ? FLD(row, IMIN(IMAX((i), 0), W - 1)) : A_ZERO)
    if (inside) {
        S2K3_LOOP(S2_LDV_IN, S2_LDS_IN)
    } else {
        S2K3_LOOP(S2_LDV_G, S2_LDS_G)
    }
#else
    if (inside) {
        CONV_LOOP(LOAD_INSIDE)
    } else {
        CONV_LOOP(LOAD_GUARDED)
    }
#endif
#if D2S
    /* a DepthToSpace fused (d2s_index.h): the residual is the shuffled output's too */
    STORE_AT(d2s_at(n, co, oy, ox0 + 8 * v, Cout, Ho, Wo), D2S, Wo - ox0)
#else
    STORE_BLOCK((long)n * Cout * Ho * Wo + ox0, 1, Wo - ox0)
#endif
}

/* ConvTranspose as a gather over output phases: along x, the outputs
 * ox = px + sx*t of one phase px see a fixed set of taps kx (those with
 * (px + pl - kx*dx) divisible by sx), each reading inputs ix = (px + pl -
 * kx*dx)/sx + t, contiguous in t. A work-item takes XB consecutive t of one
 * phase, so its input loads are vectors and its stores are spaced sx apart.
 * Rows: each output row finds its taps ky by the same divisibility.
 *
 * x: [N, Cin, H, W]; w: [Cin, Cout/groups, KH, KW]; y, res: [N, Cout, Ho, Wo].
 * NDRange: (ceil(ceil(Wo/sx) / XB), Ho, N * groups * ncb * sx). */
/** @param[in]  x       [N, Cin, H, W] input
 *  @param[in]  w       weights, [Cin, Cout/groups, KH, KW] (TW: float when fp16 storage converted them)
 *  @param[in]  bias    [Cout] bias (read when flags has 1)
 *  @param[in]  res     [N, Cout, Ho, Wo] residual (read when flags has 2 or 4)
 *  @param[out] y       [N, Cout, Ho, Wo] output
 *  @param[in]  Cin     input channels
 *  @param[in]  H       input height
 *  @param[in]  W       input width
 *  @param[in]  Cout    output channels
 *  @param[in]  Ho      output height
 *  @param[in]  Wo      output width
 *  @param[in]  Cin_g   input channels per group
 *  @param[in]  Cout_g  output channels per group
 *  @param[in]  ncb     output-channel blocks per group, ceil(Cout_g / CB)
 *  @param[in]  groups  groups
 *  @param[in]  sy      stride along y
 *  @param[in]  sx      stride along x
 *  @param[in]  pt      top pad
 *  @param[in]  pl      left pad
 *  @param[in]  dy      dilation along y
 *  @param[in]  dx      dilation along x
 *  @param[in]  flags   1 bias, 2 residual added before the activation, 4 after it
 *  @param[in]  alpha   the activation's parameter (leaky_relu slope)
 *  @param[in]  nz      the extent of NDRange dimension 2 that is real work
 *  @note -DKH, -DKW: kernel size; -DXV=1|2, -DCB=1..8: the register block (tunable); -DACT: the fused activation
 *  @note -DCLSS_CLANG_VECTORS=0|1: builtin-free loads
 *  @note -DCLSS_FP16 / -DCLSS_FP16_NATIVE: the storage precision (common.h); T and TB follow it
 */
__kernel void conv_transpose2d(__global const T *x, __global const TW *w, __global const T *bias,
                               __global const T *res, __global T *y,
                               int Cin, int H, int W, int Cout, int Ho, int Wo,
                               int Cin_g, int Cout_g, int ncb, int groups,
                               int sy, int sx, int pt, int pl, int dy, int dx,
                               int flags, float alpha, int nz)
{
    const int xb = get_global_id(0), oy = get_global_id(1), zz = get_global_id(2);
    if (oy >= Ho || zz >= nz)
        return;
    const int px = zz % sx, z = zz / sx;
    const int nt = (Wo - px + sx - 1) / sx;        /* outputs of this phase */
    const int t0 = xb * XB;
    if (t0 >= nt)
        return;
    const int cb = z % ncb, g = (z / ncb) % groups, n = z / (ncb * groups);
    const int nco = IMIN(CB, Cout_g - cb * CB);
    const int co0 = g * Cout_g + cb * CB;
    int wo[CB];
    for (int j = 0; j < CB; ++j)
        wo[j] = ((g * Cin_g) * Cout_g + cb * CB + IMIN(j, nco - 1)) * KK;

    /* Taps along x that this phase sees, and whether all their loads are inside. */
    int ixk[KW];
    int inside = 1;
    for (int kx = 0; kx < KW; ++kx) {
        const int num = px + pl - kx * dx;
        ixk[kx] = num % sx ? INT_MIN : num / sx + t0;
        if (ixk[kx] != INT_MIN && (ixk[kx] < 0 || ixk[kx] + XB > W))
            inside = 0;
    }

    A8 acc[CB][XV];
    for (int j = 0; j < CB; ++j)
        for (int v = 0; v < XV; ++v)
            acc[j][v] = (A8)A_ZERO;

    const __global T *xg = x + ((long)n * Cin + (long)g * Cin_g) * H * W;
#define CONVT_LOOP(LOAD)                                                       \
    for (int ky = 0; ky < KH; ++ky) {                                          \
        const int num = oy + pt - ky * dy;                                     \
        if (num < 0 || num % sy || num / sy >= H)                              \
            continue;                                                          \
        const long iy = num / sy;                                              \
        for (int ci = 0; ci < Cin_g; ++ci) {                                   \
            const __global T *row = xg + ((long)ci * H + iy) * W;              \
            const __global TW *wc = w + ci * Cout_g * KK;                      \
            _Pragma("unroll") for (int kx = 0; kx < KW; ++kx)                  \
                if (ixk[kx] != INT_MIN)                                        \
                    TAP(LOAD, ky * KW + kx)                                    \
        }                                                                      \
    }
#define LOADT_INSIDE(v_) FLD8(row, ixk[kx] + 8 * (v_))
#define LOADT_GUARDED(v_) ld8_guarded(row, ixk[kx] + 8 * (v_), W, 1)
    if (inside) {
        CONVT_LOOP(LOADT_INSIDE)
    } else {
        CONVT_LOOP(LOADT_GUARDED)
    }
    STORE_BLOCK((long)n * Cout * Ho * Wo + px + (long)t0 * sx, sx, nt - t0)
}

/* Half weights to float for the kernels above (fp16 storage mode), exact. */
/** @param[in]  w    [n] half weights
 *  @param[out] out  [n] the same as float (exact)
 *  @param[in]  n    elements
 *  @note -DCLSS_FP16 / -DCLSS_FP16_NATIVE: the storage precision (common.h); T and TB follow it
 */
__kernel void weights_to_float(__global const T *w, __global float *out, int n)
{
    const int i = get_global_id(0);
    if (i < n)
        out[i] = LD(w, i);
}

/* ---------------------------------------------------------------------------
 * conv2d on a channel-blocked input (the fast path for groups == 1), after
 * oneDNN's and MLAS's NCHWc kernels.
 *
 * Why: in NCHW, the inputs one work-item needs for successive input channels
 * lie H*W elements apart, so a 3x3 window over 64 channels touches 192 cache
 * lines that alias to a few L1 sets. Blocked, the ICV channels of a pixel are
 * one contiguous run: the channel loop walks one line per pixel.
 *
 * Register tile: each work-item holds NV vectors of OCV output channels (the
 * device's float vector width: 16 = one AVX-512 register) times PX output
 * pixels of one row: NV*PX accumulators. Per kernel tap and input channel it
 * loads NV weight vectors (packed once, contiguous) and PX input scalars, each
 * broadcast into NV FMAs (on x86, vfmadd231ps with a {1to16} memory operand).
 * The output is written as NCHW (transposed out of the tile), with the epilogue
 * of conv2d above (bias, residual before/after the activation), or, with
 * -DOUT_BLOCKED=1, in the blocked layout itself (OCV = the consumer's block), so
 * that a chain of blocked layers converts only at its edges (clss/model/layout.py).
 *
 * Build options: -DKH, -DKW, -DSX (compile time), -DOCV=4|8|16 (channels per
 * vector), -DNV=1..4 (vectors per work-item), -DPX=1..16 (pixels per work-item),
 * -DICV (input channels per block, any 1..16), -DACT. The reference is conv2d
 * above (fast path conv.blocked; `clss verify` compares them).
 * --------------------------------------------------------------------------- */
#ifndef OCV
#define OCV 16
#endif
#ifndef NV
#define NV 1
#endif
#ifndef PX
#define PX 8
#endif
#ifndef ICV
#define ICV 16
#endif
#ifndef OUT_BLOCKED
#define OUT_BLOCKED 0
#endif
#define OCB (OCV * NV)
typedef A AV __attribute__((ext_vector_type(OCV)));
/* element-aligned vector access to the packed weights and biases */
typedef A AVu __attribute__((ext_vector_type(OCV), aligned(sizeof(A))));
#if OCV != 16 && OCV != 8 && OCV != 4
#error "OCV must be 4, 8 or 16"
#endif
/* v stored whole into a private array (as vstoreN(v, o, p)), by a vector store, not
 * vstore16: that passes a 16-wide vector to a builtin out of line (an ABI warning on a CPU
 * without AVX-512), and pip's PoCL 3.0 then hands every program of this source back from
 * its kernel cache with no kernels in it, so each run compiled conv.cl again. */
#define VSTORE_AV(v, o, p) (*((__private AVu *)(p) + (o)) = (v))
#ifndef GATED
#define GATED 0
#endif
#if GATED && defined(CLSS_FP16)
/* a vector as the unfused graph keeps it: stored in half, read back as float */
static AV stored_av(AV v)
{
    ushort t[OCV];              /* half arrays need cl_khr_fp16; a half pointer does not */
#if OCV == 16
    /* two 8-lane halves: pip's PoCL 3.0 (LLVM 14) on an AVX-512 EPYC cannot split a
     * 16-lane float -> half conversion (see pool.cl's blocked max pool) */
    vstore_half8_rte(v.lo, 0, (__private half *)t);
    vstore_half8_rte(v.hi, 1, (__private half *)t);
    return (AV)(vload_half8(0, (__private const half *)t), vload_half8(1, (__private const half *)t));
#elif OCV == 8
    vstore_half8_rte(v, 0, (__private half *)t);
    return vload_half8(0, (__private const half *)t);
#else
    vstore_half4_rte(v, 0, (__private half *)t);
    return vload_half4(0, (__private const half *)t);
#endif
}
#define STORED_AV(v) stored_av(v)
#else
#define STORED_AV(v) (v)
#endif

/* The activation on a vector of OCV channels. sigmoid and tanh call exp / tanh: on a
 * 16-lane vector, pip's PoCL 3.0 (LLVM 14) on an AVX-512 EPYC crashed in instruction
 * selection ("Do not know how to scalarize this operator's operand!", or a segfault), which
 * turned the whole blocked path off there; two 8-lane halves compile on every compiler and
 * cost the same where 16 lanes are native. The cheap activations stay whole. */
#if OCV == 16 && (ACT == ACT_SIGMOID || ACT == ACT_TANH)
inline AV act_av(AV v, float alpha)
{
    AV r;
    r.lo = APPLY_ACT(v.lo, alpha);
    r.hi = APPLY_ACT(v.hi, alpha);
    return r;
}
#define ACT_AV(v, alpha) act_av((v), (alpha))
#else
#define ACT_AV(v, alpha) APPLY_ACT(v, alpha)
#endif
#if OCV == 16
inline AV sigmoid_av(AV v)
{
    AV r;
    r.lo = SIGMOID(v.lo);
    r.hi = SIGMOID(v.hi);
    return r;
}
#define SIGMOID_AV(v) sigmoid_av(v)
#else
#define SIGMOID_AV(v) SIGMOID(v)
#endif

/* One pixel's vector of OCV output channels stored whole at p (the blocked layout's
 * epilogue, conv2d_blocked's and conv2d_wino's): element by element in half storage. */
#if defined(CLSS_FP16)
#define STORE_BLOCK_AV(p, v) do { A u_[OCV]; VSTORE_AV((v), 0, u_);            \
        for (int k_ = 0; k_ < OCV; ++k_) FST((p), k_, u_[k_]); } while (0)
#else
#define STORE_BLOCK_AV(p, v) (*(__global AVu *)(p) = (v))
#endif
/* Lane j of 8 consecutive pixels p.. of a private tile u[pixel][OCV], as one vector: an
 * NCHW epilogue's run of a channel, stored with one FST8 */
#define TILE_RUN8(u, p, j) ((A8)((u)[p][j], (u)[(p) + 1][j], (u)[(p) + 2][j], (u)[(p) + 3][j], \
                                 (u)[(p) + 4][j], (u)[(p) + 5][j], (u)[(p) + 6][j], (u)[(p) + 7][j]))

/* The layout kernels take the block sizes as arguments, not -D options: they are
 * memory-bound, and one build serves every layer (under oclgrind a build is slow). */

/* The work-item of to_blocked_at and to_blocked_table: 16 pixels (ix0.., np of them
 * inside the row) of row iy of output block cb of image n; dst: the first pixel's block,
 * of element type E. */
#define TO_BLOCKED_ITEM(E)                                                       \
    const int ix0 = get_global_id(0) * 16, iy = get_global_id(1), z = get_global_id(2); \
    if (ix0 >= W || iy >= H)                                                     \
        return;                                                                  \
    const int n = z / nblk, cb = d0 / B + z % nblk;                              \
    const int np = IMIN(16, W - ix0);                                            \
    const long hw = (long)H * W;                                                 \
    __global E *dst = xb + ((((long)n * CBd + cb) * H + iy) * W + ix0) * B

/* NCHW -> blocked [N][CBd][H][W][B]: `count` channels of x from channel c0 on land at
 * channels d0.. of the blocked output, whose channels past Ctot are zeroed. The layout
 * transform of a conv2d_blocked input (c0 = d0 = 0, count = Ctot = C), and one input of a
 * channel concat written straight into the blocked layout (clss/model/layout.py: a concat
 * that feeds only blocked convs; a concat input, or the channel range a Slice took; one
 * launch per input, each writing only its own lanes). Pure data movement (bits through
 * TB). A work-item moves 16 pixels of a row: per channel one 64-byte run (channel planes
 * H*W apart often alias to one L1 set, so each line is read whole, once), written into
 * its lane of a contiguous 16*B run.
 * NDRange: (ceil(W / 16), H, N * nblk), nblk = the output blocks the range touches.
 * @param[in]  x      [N, Cx, H, W] concat input (NCHW)
 * @param[out] xb     [N, CBd, H, W, B] blocked output
 * @param[in]  Cx     channels of x
 * @param[in]  c0     first channel of x taken
 * @param[in]  count  channels taken
 * @param[in]  H      height
 * @param[in]  W      width
 * @param[in]  CBd    blocks of the output
 * @param[in]  B      channels per block
 * @param[in]  d0     the output channel of x's channel c0
 * @param[in]  Ctot   the concat's channels (the rest of the last block is zero)
 * @param[in]  nblk   output blocks the range [d0, d0 + count) touches
 */
__kernel void to_blocked_at(__global const TB *x, __global TB *xb, int Cx, int c0, int count, int H, int W,
                            int CBd, int B, int d0, int Ctot, int nblk)
{
    TO_BLOCKED_ITEM(TB);
    for (int j = 0; j < B; ++j) {
        const int dc = cb * B + j;
        if (dc >= Ctot) {
            for (int p = 0; p < np; ++p)
                dst[p * B + j] = (TB)0;
            continue;
        }
        if (dc < d0 || dc >= d0 + count)
            continue;
        const __global TB *s = x + ((long)n * Cx + c0 + dc - d0) * hw + (long)iy * W + ix0;
        if (np == 16) {
            /* two 8-wide loads, not one vload16: pip's PoCL 3.0 on an AVX-512 EPYC returned
             * wrong lanes 8-15 from a uint16 load here (fp32; ushort16 in fp16 was right),
             * which kept the whole blocked path off in fp32 there */
            const TB8 a = TB_LD8(s), b = TB_LD8(s + 8);
            dst[0 * B + j] = a.s0; dst[1 * B + j] = a.s1; dst[2 * B + j] = a.s2; dst[3 * B + j] = a.s3;
            dst[4 * B + j] = a.s4; dst[5 * B + j] = a.s5; dst[6 * B + j] = a.s6; dst[7 * B + j] = a.s7;
            dst[8 * B + j] = b.s0; dst[9 * B + j] = b.s1; dst[10 * B + j] = b.s2; dst[11 * B + j] = b.s3;
            dst[12 * B + j] = b.s4; dst[13 * B + j] = b.s5; dst[14 * B + j] = b.s6; dst[15 * B + j] = b.s7;
        } else {
            for (int p = 0; p < np; ++p)
                dst[p * B + j] = s[p];
        }
    }
}

/* A channel concat of one NCHW tensor's channels, some times a channel of a second one
 * (a scale map), into the blocked layout: NSRR's input stacks, whose concat inputs are all
 * channel ranges of `stack` (times a channel of `r`), in one launch. Each work-item writes
 * every lane of its block for 16 pixels, so each output line is written by one
 * work-item, not once per concat input (to_blocked_at: a launch per input). Output
 * channel dc is channel tab[2 dc] of x, times channel tab[2 dc + 1] of s where that is
 * >= 0; tab[2 dc] = -1 leaves the lane to another launch (a concat of several tensors: a
 * launch per scaled input); channels past Ctot are zero. The product is the elementwise
 * Mul's (a * b in the arithmetic type, stored rounded to nearest even); an unscaled
 * channel moves bits.
 * NDRange: (ceil(W / 16), H, N * CBd).
 * @param[in]  x      [N, Cx, H, W] (NCHW)
 * @param[in]  s      [N, Cs, H, W] scale maps (NCHW; x where no channel is scaled)
 * @param[out] xb     [N, CBd, H, W, B] blocked output
 * @param[in]  tab    [Ctot, 2] int: (channel of x or -1, channel of s or -1) per output channel
 * @param[in]  Cx     channels of x
 * @param[in]  Cs     channels of s
 * @param[in]  H      height
 * @param[in]  W      width
 * @param[in]  CBd    blocks of the output
 * @param[in]  B      channels per block
 * @param[in]  Ctot   the concat's channels */
__kernel void to_blocked_table(__global const T *x, __global const T *s, __global T *xb,
                               __global const int *tab, int Cx, int Cs, int H, int W, int CBd, int B,
                               int Ctot)
{
    const int nblk = CBd, d0 = 0;
    TO_BLOCKED_ITEM(T);
    const long pix = (long)iy * W + ix0;
    for (int j = 0; j < B; ++j) {
        const int dc = cb * B + j;
        if (dc >= Ctot) {
            for (int p = 0; p < np; ++p)
                ST(dst, p * B + j, A_ZERO);
            continue;
        }
        const int cx = tab[2 * dc], cs = tab[2 * dc + 1];
        if (cx < 0)
            continue;
        const __global T *v = x + ((long)n * Cx + cx) * hw + pix;
        if (cs < 0) {       /* data movement: the bits */
            for (int p = 0; p < np; ++p)
                ((__global TB *)dst)[p * B + j] = ((__global const TB *)v)[p];
        } else {
            const __global T *m = s + ((long)n * Cs + cs) * hw + pix;
            for (int p = 0; p < np; ++p)
                ST(dst, p * B + j, LD(v, p) * LD(m, p));
        }
    }
}

/* Weights [Cout, Cin, kk] -> packed [ncb][Cb][kk][icv][ocb] in the arithmetic
 * type A, zero past Cout and Cin. NDRange: (ocb, icv, ncb * Cb * kk). */
/** @param[in]  w     [Cout, Cin, KH, KW] weights (kk = KH * KW taps)
 *  @param[out] wp    [ncb, Cb, KH, KW, icv, ocb] packed
 *  @param[in]  Cout  output channels
 *  @param[in]  Cin   input channels
 *  @param[in]  Cb    input channel blocks, ceil(Cin / icv)
 *  @param[in]  kk    taps per channel
 *  @param[in]  icv   input channels per block
 *  @param[in]  ocb   output channels per block (OCV * NV of the conv)
 */
__kernel void pack_blocked_weights(__global const T *w, __global A *wp, int Cout, int Cin, int Cb,
                                   int kk, int icv, int ocb)
{
    const int j = get_global_id(0), cc = get_global_id(1), z = get_global_id(2);
    const int k = z % kk, c = (z / kk) % Cb, cb = z / (kk * Cb);
    const int co = cb * ocb + j, ci = c * icv + cc;
    wp[((long)z * icv + cc) * ocb + j] =
        co < Cout && ci < Cin ? LD(w, ((long)co * Cin + ci) * kk + k) : A_ZERO;
}

/* Bias, padded to whole output blocks (zero where absent). NDRange: (ncb * ocb). */
/** @param[in]  b      [Cout] bias
 *  @param[out] bp     [ncb * ocb] padded bias
 *  @param[in]  Cout   output channels
 *  @param[in]  has_b  0: no bias (zeros)
 */
__kernel void pack_blocked_bias(__global const T *b, __global A *bp, int Cout, int has_b)
{
    const int i = get_global_id(0);
    bp[i] = has_b && i < Cout ? LD(b, i) : A_ZERO;
}

/** @param[in]  x      [N, Cb, H, W, ICV] blocked input (to_blocked)
 *  @param[in]  wp     packed weights (pack_blocked_weights)
 *  @param[in]  bp     packed bias (pack_blocked_bias)
 *  @param[in]  res    [N, Cout, Ho, Wo] residual (read when flags has 2 or 4)
 *  @param[out] y      [N, Cout, Ho, Wo] output (NCHW), or with -DOUT_BLOCKED=1
 *                     [N, ceil(Cout / OCV), Ho, Wo, OCV] (blocked, for a blocked consumer)
 *  @param[in]  Cb     input channel blocks
 *  @param[in]  H      input height
 *  @param[in]  W      input width
 *  @param[in]  Cout   output channels
 *  @param[in]  Ho     output height
 *  @param[in]  Wo     output width
 *  @param[in]  ncb    output channel blocks, ceil(Cout / OCB)
 *  @param[in]  sy     stride along y
 *  @param[in]  pt     top pad
 *  @param[in]  pl     left pad
 *  @param[in]  dy     dilation along y
 *  @param[in]  dx     dilation along x
 *  @param[in]  flags  2 residual added before the activation, 4 after it (the bias is always added)
 *  @param[in]  alpha  the activation's parameter (leaky_relu slope)
 *  @param[in]  nz     the extent of NDRange dimension 2 that is real work (N * ncb)
 *  @note NDRange: (ceil(Wo / PX), Ho, N * ncb)
 *  @note -DKH, -DKW, -DSX; -DOCV, -DNV, -DPX, -DICV: the register tile and block (tunable); -DACT
 */
__kernel void conv2d_blocked(__global const T *x, __global const A *wp, __global const A *bp,
                             __global const T *res, __global T *y,
                             int Cb, int H, int W, int Cout, int Ho, int Wo, int ncb,
                             int sy, int pt, int pl, int dy, int dx,
                             int flags, float alpha, int nz)
{
    const int xb = get_global_id(0), oy = get_global_id(1), z = get_global_id(2);
    if (xb * PX >= Wo || oy >= Ho || z >= nz)
        return;
    const int cb = z % ncb, n = z / ncb;
    const int co0 = cb * OCB;
    const int ox0 = xb * PX, ix0 = ox0 * SX - pl, iy0 = oy * sy - pt;
    const int inside = ix0 >= 0 && ix0 + (PX - 1) * SX + (KW - 1) * dx < W;

    AV acc[NV][PX];
    for (int v = 0; v < NV; ++v)
        for (int p = 0; p < PX; ++p)
            acc[v][p] = (AV)A_ZERO;

    const __global T *xg = x + (long)n * Cb * H * W * ICV;
    const __global A *wg = wp + (long)cb * Cb * KK * ICV * OCB;
    const int ky0 = iy0 < 0 ? (-iy0 + dy - 1) / dy : 0;
    const int ky1 = IMIN(KH, (H - iy0 + dy - 1) / dy);
/* The tap loop is not unrolled: unrolled, the compiler keeps inputs shared by
 * neighbouring taps in registers and spills the tile. Offsets are compile-time
 * constants from one pointer per tap, so each load folds into its FMA. */
#define BLOCKED_LOOP(INSIDE)                                                     \
    for (int c = 0; c < Cb; ++c) {                                               \
        for (int ky = ky0; ky < ky1; ++ky) {                                     \
            const __global T *row = xg + ((long)c * H + iy0 + ky * dy) * W * ICV; \
            const __global A *wr = wg + (c * KH + ky) * KW * ICV * OCB;          \
            _Pragma("nounroll") for (int kx = 0; kx < KW; ++kx) {                \
                const int ixk = ix0 + kx * dx;                                   \
                const __global T *xp = row + (long)ixk * ICV;                    \
                const __global A *wk = wr + kx * ICV * OCB;                      \
                _Pragma("unroll") for (int cc = 0; cc < ICV; ++cc) {             \
                    AV wv[NV];                                                   \
                    _Pragma("unroll") for (int v = 0; v < NV; ++v)               \
                        wv[v] = *(__global const AVu *)(wk + cc * OCB + v * OCV); \
                    _Pragma("unroll") for (int p = 0; p < PX; ++p) {             \
                        const int q = ixk + p * SX;                              \
                        const A s = (INSIDE || (q >= 0 && q < W))                \
                            ? FLD(xp, p * SX * ICV + cc) : A_ZERO;               \
                        _Pragma("unroll") for (int v = 0; v < NV; ++v)           \
                            acc[v][p] += wv[v] * s;                              \
                    }                                                            \
                }                                                                \
            }                                                                    \
        }                                                                        \
    }
    if (inside) {
        BLOCKED_LOOP(1)
    } else {
        BLOCKED_LOOP(0)
    }

    const int np = IMIN(PX, Wo - ox0);
#if GATED
    /* A gated conv (clss/model/passes.py fuse_gated_conv): the weights interleave the
     * feature conv's and the gate conv's output blocks, so vectors 2v and 2v + 1 are a
     * block of features and its gates; out = act(f + bf) * sigmoid(g + bg), each factor
     * rounded to the storage precision as the unfused graph stores it, the product the
     * Mul's. Cout counts the output (feature) channels; NV is even. */
#if NV % 2
#error "GATED needs an even NV"
#endif
#define ENV (NV / 2)
    const int eco0 = cb * ENV * OCV;
    for (int v = 0; v < ENV; ++v) {
        const AV bf = *(__global const AVu *)(bp + co0 + 2 * v * OCV);
        const AV bg = *(__global const AVu *)(bp + co0 + (2 * v + 1) * OCV);
        for (int p = 0; p < PX; ++p)
            acc[v][p] = STORED_AV(ACT_AV(acc[2 * v][p] + bf, alpha))
                        * STORED_AV(SIGMOID_AV(acc[2 * v + 1][p] + bg));
    }
#else
#define ENV NV
    const int eco0 = co0;
#define EPI_BIAS(v) (*(__global const AVu *)(bp + co0 + (v) * OCV))
#endif
#if OUT_BLOCKED
    /* Blocked output [N][ceil(Cout / OCV)][Ho][Wo][OCV] for a blocked consumer
     * (clss/model/layout.py): each accumulator vector is one pixel's channel block,
     * stored whole and contiguous; channels past Cout hold act(0) (zero weights and
     * bias), which the consumers' zero weights ignore. No residual here. */
    const int cbo = (Cout + OCV - 1) / OCV;
    for (int v = 0; v < ENV; ++v) {
        const int ob = cb * ENV + v;
        if (ob >= cbo)
            break;
        __global T *yo = y + ((((long)n * cbo + ob) * Ho + oy) * Wo + ox0) * OCV;
        for (int p = 0; p < np; ++p) {
#if GATED
            const AV t = acc[v][p];
#else
            const AV t = ACT_AV(acc[v][p] + EPI_BIAS(v), alpha);
#endif
            STORE_BLOCK_AV(yo + p * OCV, t);
        }
    }
#else
    const long hwo = (long)Ho * Wo;
    const long o0 = ((long)n * Cout + eco0) * hwo + (long)oy * Wo + ox0;
    const int enco = IMIN(ENV * OCV, Cout - eco0);
    for (int v = 0; v < ENV; ++v) {
        /* The tile goes through a private array by vstore: lanes read back by a
         * variable index (a union, or a subscript) confuse oclgrind's
         * uninitialised-value tracking on the kernel's second launch. */
        A u[PX][OCV];
        for (int p = 0; p < PX; ++p) {
#if GATED
            AV t = acc[v][p];
#else
            AV t = acc[v][p] + EPI_BIAS(v);
            if (!(flags & (F_RES_BEFORE | F_RES_AFTER)))
                t = ACT_AV(t, alpha);
#endif
            VSTORE_AV(t, 0, u[p]);
        }
        for (int j = 0; j < OCV; ++j) {
            const int c = v * OCV + j;
            if (c >= enco)
                break;
            const long o = o0 + (long)c * hwo;
            if (flags & (F_RES_BEFORE | F_RES_AFTER)) {
                for (int p = 0; p < np; ++p) {
                    const A r = FLD(res, o + p);
                    A t = u[p][j];
                    if (flags & F_RES_BEFORE)
                        t += r;
                    t = APPLY_ACT(t, alpha);
                    if (flags & F_RES_AFTER)
                        t += r;
                    FST(y, o + p, t);
                }
            } else if (np == PX) {
#if PX % 8 == 0 && !defined(NO_VST)
                /* a channel's run of pixels as whole 8-wide stores: scattered scalar
                 * stores to OCV * NV planes made the NCHW epilogue cost as much as a
                 * third of the conv (NSRD's ConvLSTM gates) */
                for (int p = 0; p < PX; p += 8)
                    FST8(y, o + p, TILE_RUN8(u, p, j));
#else
                for (int p = 0; p < PX; ++p)
                    FST(y, o + p, u[p][j]);
#endif
            } else {
                for (int p = 0; p < np; ++p)
                    FST(y, o + p, u[p][j]);
            }
        }
    }
#endif
}

/* ---------------------------------------------------------------------------
 * conv2d_wino: a 3x3, stride-1, dilation-1 convolution by Winograd's F(2x2, 3x3)
 * (Lavin & Gray 2016) on a channel-blocked input, blocked or NCHW output. Each 4x4 input
 * tile d gives a 2x2 output tile Y = A^T [sum over input channels (U . V)] A, with
 * V = B^T d B (the input transform, 16 values per channel) and U = G g G^T (the weights,
 * transformed once on the host, clss/ops/conv.py _conv2d_wino): 16 FMAs per input channel
 * for 4 outputs where the direct conv spends 36, so 2.25x fewer, for the transforms'
 * adds and a rounding that differs from the direct sum (within the default tolerance;
 * fast path conv.winograd, checked against conv2d_blocked).
 *
 * A work-item takes TT tiles along x (2 output rows, 2*TT columns) and OBI blocks of
 * NV*OCV output channels. Per input channel block it transforms its tiles' inputs once
 * into a private array (its ICV channels 8 lanes at a time where ICV is a multiple of 8),
 * then, per transform position q (16), runs the register tile of TT x NV accumulator
 * vectors over the block's channels: one weight vector per NV, a broadcast per tile,
 * as conv2d_blocked does per pixel. The 16 positions' sums live in a private array
 * between channel blocks (loaded and stored once per block and position: ICV * TT * NV
 * FMAs each). Covering every output channel in one work-item (OBI) does the input
 * transform once per tile, not once per output block.
 *
 * Build options: -DOCV=8|16, -DNV, -DTT, -DOBI, -DICV (1..16), -DACT, -DWINO_WIDE,
 * -DOUT_BLOCKED=1 (blocked output) or 0 (NCHW). No residual.
 * NDRange: (ceil(Wo / (2 * TT)), ceil(Ho / 2), N * ncb / OBI).
 * @param[in]  x      [N, Cb, H, W, ICV] blocked input
 * @param[in]  u      [ncb, Cb, 16, ICV, OCB] transformed weights (A), zero past Cout and Cin
 * @param[in]  bp     [ncb * OCB] bias (A), zero where none
 * @param[out] y      [N, ceil(Cout / OCV), Ho, Wo, OCV] blocked output (-DOUT_BLOCKED=1), or
 *                    [N, Cout, Ho, Wo] (NCHW)
 * @param[in]  Cb     input channel blocks
 * @param[in]  H      input height
 * @param[in]  W      input width
 * @param[in]  Cout   output channels
 * @param[in]  Ho     output height
 * @param[in]  Wo     output width
 * @param[in]  ncb    output channel blocks of OCB (a multiple of OBI)
 * @param[in]  pt     top pad
 * @param[in]  pl     left pad
 * @param[in]  alpha  the activation's parameter (leaky_relu slope)
 * @param[in]  nz     the extent of NDRange dimension 2 that is real work (N * ncb / OBI)
 * --------------------------------------------------------------------------- */
#if defined(TT) && defined(OBI)
#ifndef WINO_WIDE
#define WINO_WIDE 0
#endif
/* lanes per step of the input transform: a whole block of 16 at once with -DWINO_WIDE=1
 * (PoCL), 8 otherwise (oclgrind crashed on the 16-wide form, as on conv2d_thin's) */
#if ICV == 16 && WINO_WIDE
#define WL 16
typedef A WV __attribute__((ext_vector_type(16)));
typedef A WVu __attribute__((ext_vector_type(16), aligned(sizeof(A))));
#if defined(CLSS_FP16) || defined(CLSS_FP16_NATIVE)
#define WLD(p, i) ((WV)(FLD8(p, i), FLD8(p, (i) + 8)))
#else
#define WLD(p, i) (*(__global const WVu *)((p) + (i)))
#endif
#elif ICV % 8 == 0
#define WL 8
typedef A8 WV;
typedef A WVu __attribute__((ext_vector_type(8), aligned(sizeof(A))));
#define WLD(p, i) FLD8(p, i)
#else
#define WL 1
typedef A WV;
typedef A WVu;
#define WLD(p, i) FLD(p, i)
#endif
/* a private store as a clang vector: vstore8/16 are out-of-line calls on PoCL's CPUs */
#define WPUT(a, v) (*(__private WVu *)(a) = (v))
#define WNC (2 * TT + 2)        /* input columns of TT tiles */

__kernel void conv2d_wino(__global const T *x, __global const A *u, __global const A *bp,
                          __global T *y, int Cb, int H, int W, int Cout, int Ho, int Wo,
                          int ncb, int pt, int pl, float alpha, int nz)
{
    const int xb = get_global_id(0), ty = get_global_id(1), z = get_global_id(2);
    const int oy0 = 2 * ty, ox0 = xb * 2 * TT;
    if (ox0 >= Wo || oy0 >= Ho || z >= nz)
        return;
    const int nzb = ncb / OBI, cb = z % nzb, n = z / nzb;
    const int iy0 = oy0 - pt, ix0 = ox0 - pl;
    const int inside = ix0 >= 0 && ix0 + WNC <= W && iy0 >= 0 && iy0 + 4 <= H;
    AV acc[OBI][16][TT][NV];
    for (int o = 0; o < OBI; ++o)
        for (int q = 0; q < 16; ++q)
            for (int t = 0; t < TT; ++t)
                for (int v = 0; v < NV; ++v)
                    acc[o][q][t][v] = (AV)A_ZERO;
    const __global T *xg = x + (long)n * Cb * H * W * ICV;
    for (int c = 0; c < Cb; ++c) {
        A V[TT][16][ICV];       /* V = B^T d B of each tile, per channel */
        _Pragma("unroll") for (int l = 0; l < ICV; l += WL) {
            WV e[4][WNC];       /* B^T d: the tiles' columns transformed along y */
            _Pragma("unroll") for (int j = 0; j < WNC; ++j) {
                WV d[4];
                _Pragma("unroll") for (int r = 0; r < 4; ++r) {
                    const int iy = iy0 + r, ix = ix0 + j;
                    d[r] = (inside || (iy >= 0 && iy < H && ix >= 0 && ix < W))
                        ? WLD(xg, (((long)c * H + iy) * W + ix) * ICV + l) : (WV)A_ZERO;
                }
                e[0][j] = d[0] - d[2];
                e[1][j] = d[1] + d[2];
                e[2][j] = d[2] - d[1];
                e[3][j] = d[1] - d[3];
            }
            _Pragma("unroll") for (int t = 0; t < TT; ++t)      /* then along x */
                _Pragma("unroll") for (int i = 0; i < 4; ++i) {
                    const WV a0 = e[i][2 * t], a1 = e[i][2 * t + 1];
                    const WV a2 = e[i][2 * t + 2], a3 = e[i][2 * t + 3];
                    WPUT(&V[t][4 * i + 0][l], a0 - a2);
                    WPUT(&V[t][4 * i + 1][l], a1 + a2);
                    WPUT(&V[t][4 * i + 2][l], a2 - a1);
                    WPUT(&V[t][4 * i + 3][l], a1 - a3);
                }
        }
        _Pragma("nounroll") for (int o = 0; o < OBI; ++o) {
            const __global A *wb = u + ((long)((cb * OBI + o) * Cb + c) * 16) * ICV * OCB;
            _Pragma("nounroll") for (int q = 0; q < 16; ++q) {
                AV a[TT][NV];
                _Pragma("unroll") for (int t = 0; t < TT; ++t)
                    _Pragma("unroll") for (int v = 0; v < NV; ++v)
                        a[t][v] = acc[o][q][t][v];
                const __global A *wq = wb + q * ICV * OCB;
                _Pragma("unroll") for (int cc = 0; cc < ICV; ++cc) {
                    AV wv[NV];
                    _Pragma("unroll") for (int v = 0; v < NV; ++v)
                        wv[v] = *(__global const AVu *)(wq + cc * OCB + v * OCV);
                    _Pragma("unroll") for (int t = 0; t < TT; ++t) {
                        const A s = V[t][q][cc];
                        _Pragma("unroll") for (int v = 0; v < NV; ++v)
                            a[t][v] += wv[v] * s;
                    }
                }
                _Pragma("unroll") for (int t = 0; t < TT; ++t)
                    _Pragma("unroll") for (int v = 0; v < NV; ++v)
                        acc[o][q][t][v] = a[t][v];
            }
        }
    }
    /* Y = A^T M A, then bias and activation; blocked out: stored whole per pixel (as
     * conv2d_blocked's blocked epilogue: channels past Cout hold act(0)); NCHW out: through a
     * private tile, each channel's run of 2 * TT pixels of a row stored 8 at a time */
    const int cbo = (Cout + OCV - 1) / OCV;
    for (int o = 0; o < OBI; ++o)
        for (int v = 0; v < NV; ++v) {
            const int blk = (cb * OBI + o) * NV + v;
            if (blk >= cbo)
                break;
            const AV b = *(__global const AVu *)(bp + (long)blk * OCV);
#if !OUT_BLOCKED
            A u[2][2 * TT][OCV];
#endif
            for (int t = 0; t < TT; ++t) {
                AV r0[4], r1[4];
                for (int j = 0; j < 4; ++j) {
                    r0[j] = acc[o][j][t][v] + acc[o][4 + j][t][v] + acc[o][8 + j][t][v];
                    r1[j] = acc[o][4 + j][t][v] - acc[o][8 + j][t][v] - acc[o][12 + j][t][v];
                }
                AV ot[2][2];
                ot[0][0] = r0[0] + r0[1] + r0[2];
                ot[0][1] = r0[1] - r0[2] - r0[3];
                ot[1][0] = r1[0] + r1[1] + r1[2];
                ot[1][1] = r1[1] - r1[2] - r1[3];
                for (int dy = 0; dy < 2; ++dy)
                    for (int dx = 0; dx < 2; ++dx) {
                        const AV r = ACT_AV(ot[dy][dx] + b, alpha);
#if OUT_BLOCKED
                        const int oy = oy0 + dy, ox = ox0 + 2 * t + dx;
                        if (oy >= Ho || ox >= Wo)
                            continue;
                        STORE_BLOCK_AV(y + ((((long)n * cbo + blk) * Ho + oy) * Wo + ox) * OCV, r);
#else
                        VSTORE_AV(r, 0, u[dy][2 * t + dx]);
#endif
                    }
            }
#if !OUT_BLOCKED
            const int np = IMIN(2 * TT, Wo - ox0);
            for (int j = 0; j < OCV; ++j) {
                const int c = blk * OCV + j;
                if (c >= Cout)
                    break;
                for (int dy = 0; dy < 2 && oy0 + dy < Ho; ++dy) {
                    const long oo = (((long)n * Cout + c) * Ho + oy0 + dy) * Wo + ox0;
#if (2 * TT) % 8 == 0
                    if (np == 2 * TT) {
                        for (int p = 0; p < 2 * TT; p += 8)
                            FST8(y, oo + p, TILE_RUN8(u[dy], p, j));
                        continue;
                    }
#endif
                    for (int p = 0; p < np; ++p)
                        FST(y, oo + p, u[dy][p][j]);
                }
            }
#endif
        }
}
#endif

/* ---------------------------------------------------------------------------
 * conv2d_thin: a convolution with few output channels (fewer than 8: an RGB or
 * weight head, NSRR's last layers) on a channel-blocked input [N][Cb][H][W][ICV]
 * (ICV = 8 or 16: a blocked conv's output), NCHW out.
 *
 * conv2d_blocked vectorises over output channels, so a 3-channel head fills 3 of
 * 16 lanes; the NCHW conv2d leaves its input's producer to store NCHW (a transposing
 * store, the slow epilogue of a blocked conv). Here the lanes are the input block's
 * channels: per tap, one vector load of a pixel's ICV channels and one FMA per output
 * channel, summed across the lanes once at the end. A work-item holds OC output
 * channels x PX pixels of one row. Stride 1, dilation 1. The epilogue is conv2d's
 * (bias, a residual before or after the activation). The lane sum is a tree, not
 * conv2d's channel order, so the result matches the reference within the default
 * tolerance (fast path conv.thin).
 *
 * Build options: -DKH, -DKW, -DICV=8|16, -DOC=1..4, -DPX=1..8, -DACT.
 * NDRange: (ceil(Wo / PX), Ho, N * ng), ng = ceil(Cout / OC).
 * @param[in]  x      [N, Cb, H, W, ICV] input (blocked; channels past Cin have zero weights)
 * @param[in]  wp     [ng, Cb, KH, KW, OC, ICV] packed weights (A), zero past Cout and Cin
 * @param[in]  bp     [ng * OC] bias (A), zero where none
 * @param[in]  res    [N, Cout, Ho, Wo] residual (flags), or unused
 * @param[out] y      [N, Cout, Ho, Wo] output (NCHW)
 * @param[in]  Cb     input channel blocks
 * @param[in]  H      input height
 * @param[in]  W      input width
 * @param[in]  Cout   output channels
 * @param[in]  Ho     output height
 * @param[in]  Wo     output width
 * @param[in]  pt     top padding
 * @param[in]  pl     left padding
 * @param[in]  flags  F_RES_BEFORE / F_RES_AFTER
 * @param[in]  alpha  leaky ReLU slope
 * @param[in]  ng     output channel groups of OC
 * --------------------------------------------------------------------------- */
#if defined(ICV) && (ICV == 8 || ICV == 16) && defined(OC)
/* A pixel's ICV channels as one ICV-wide vector (-DTHIN_WIDE=1, PoCL) or as NH 8-lane
 * halves (oclgrind crashed on arrays of 16-wide vectors); the sums are the same. */
#ifndef THIN_WIDE
#define THIN_WIDE 0
#endif
typedef A A8u __attribute__((ext_vector_type(8), aligned(sizeof(A))));
#if THIN_WIDE
#define NH 1
#define HL ICV
typedef A AH __attribute__((ext_vector_type(ICV)));
typedef A AHu __attribute__((ext_vector_type(ICV), aligned(sizeof(A))));
#if ICV == 16
#define THIN_LD(p, i) ((AH)(FLD8(p, i), FLD8(p, (i) + 8)))
#define THIN_FOLD(a) ((a)[0].lo + (a)[0].hi)
#else
#define THIN_LD(p, i) FLD8(p, i)
#define THIN_FOLD(a) ((a)[0])
#endif
#else
#define NH (ICV / 8)
#define HL 8
typedef A8 AH;
typedef A8u AHu;
#define THIN_LD(p, i) FLD8(p, i)
#if ICV == 16
#define THIN_FOLD(a) ((a)[0] + (a)[1])
#else
#define THIN_FOLD(a) ((a)[0])
#endif
#endif

/* the lanes' sum, as a tree (the halves first) */
static inline A thin_sum(A8 s8)
{
    const A4 s4 = s8.lo + s8.hi;
    return (s4.s0 + s4.s2) + (s4.s1 + s4.s3);
}

__kernel void conv2d_thin(__global const T *x, __global const A *wp, __global const A *bp,
                          __global const T *res, __global T *y,
                          int Cb, int H, int W, int Cout, int Ho, int Wo, int pt, int pl,
                          int flags, float alpha, int ng)
{
    const int xb = get_global_id(0), oy = get_global_id(1), z = get_global_id(2);
    if (xb * PX >= Wo || oy >= Ho)
        return;
    const int g = z % ng, n = z / ng;
    const int ox0 = xb * PX, ix0 = ox0 - pl, iy0 = oy - pt;
    const int inside = ix0 >= 0 && ix0 + (PX - 1) + (KW - 1) < W;

    AH acc[OC][PX][NH];
    for (int o = 0; o < OC; ++o)
        for (int p = 0; p < PX; ++p)
            for (int h = 0; h < NH; ++h)
                acc[o][p][h] = (AH)A_ZERO;

    const __global T *xg = x + (long)n * Cb * H * W * ICV;
    const __global A *wg = wp + (long)g * Cb * KH * KW * OC * ICV;
    const int ky0 = IMAX(0, -iy0), ky1 = IMIN(KH, H - iy0);
#define THIN_LOOP(INSIDE)                                                        \
    for (int c = 0; c < Cb; ++c) {                                               \
        for (int ky = ky0; ky < ky1; ++ky) {                                     \
            const __global T *row = xg + ((long)c * H + iy0 + ky) * W * ICV;     \
            const __global A *wr = wg + (c * KH + ky) * KW * OC * ICV;           \
            _Pragma("nounroll") for (int kx = 0; kx < KW; ++kx) {                \
                AH wv[OC][NH];                                                   \
                _Pragma("unroll") for (int o = 0; o < OC; ++o)                   \
                    _Pragma("unroll") for (int h = 0; h < NH; ++h)               \
                        wv[o][h] = *(__global const AHu *)(wr + (kx * OC + o) * ICV + h * HL); \
                _Pragma("unroll") for (int p = 0; p < PX; ++p) {                 \
                    const int q = ix0 + kx + p;                                  \
                    const int in = INSIDE || (q >= 0 && q < W);                  \
                    _Pragma("unroll") for (int h = 0; h < NH; ++h) {             \
                        const AH s = in ? THIN_LD(row, (long)q * ICV + h * HL) : (AH)A_ZERO; \
                        _Pragma("unroll") for (int o = 0; o < OC; ++o)           \
                            acc[o][p][h] += wv[o][h] * s;                        \
                    }                                                            \
                }                                                                \
            }                                                                    \
        }                                                                        \
    }
    if (inside) {
        THIN_LOOP(1)
    } else {
        THIN_LOOP(0)
    }

    /* the epilogue on 8-lane vectors of the tile's OC x PX outputs: a scalar tanh or exp
     * is a library call per output on PoCL, and a 4-wide one little better */
#if OC * PX > 16
#error "conv2d_thin: OC * PX must be at most 16"
#endif
    const int np = IMIN(PX, Wo - ox0);
    const long o0 = (((long)n * Cout + g * OC) * Ho + oy) * Wo + ox0, hwo = (long)Ho * Wo;
    A sv[16], rv[16], u[16];
    for (int e = 0; e < 16; ++e) {
        sv[e] = A_ZERO;
        rv[e] = A_ZERO;
    }
    for (int o = 0; o < OC; ++o) {
        if (g * OC + o >= Cout)
            break;
        const A b = bp[g * OC + o];
        for (int p = 0; p < PX; ++p)
            sv[o * PX + p] = thin_sum(THIN_FOLD(acc[o][p])) + b;
        if (flags & (F_RES_BEFORE | F_RES_AFTER))
            for (int p = 0; p < np; ++p)
                rv[o * PX + p] = FLD(res, o0 + o * hwo + p);
    }
    for (int e = 0; e < OC * PX; e += 8) {
        A8 t = *(const A8u *)(sv + e);
        const A8 r = *(const A8u *)(rv + e);
        if (flags & F_RES_BEFORE)
            t += r;
        t = APPLY_ACT(t, alpha);
        if (flags & F_RES_AFTER)
            t += r;
        *(A8u *)(u + e) = t;
    }
    for (int o = 0; o < OC; ++o) {
        if (g * OC + o >= Cout)
            break;
        for (int p = 0; p < np; ++p)
            FST(y, o0 + o * hwo + p, u[o * PX + p]);
    }
}
#endif
