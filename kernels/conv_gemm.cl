/* conv2d_gemm: Conv as an implicit GEMM, the GPU rows of the conv family's variant table
 * (clss/ops/conv.py VARIANTS, clss/ops/variants.py). One source, three inner products chosen by -D:
 *
 *   Y[co, p] = sum_k W[co, k] * X[k, p]     per image n and group g, where
 *   co: an output channel of the group, p = oy * Wo + ox an output pixel,
 *   k = (ci * KH + ky) * KW + kx, and X[k, p] the input pixel that tap k of output p reads
 *   (zero in the padding): the im2col matrix, never written out.
 *
 * A work-group computes a TM x TN tile of Y (TM channels x TN pixels). It walks k in
 * steps of TK:
 *   CONV_LOCAL=1  (default) the group stages the W tile (TM x TK) and the X tile
 *                 (TK x TN) in local memory, then each work-item multiplies an RM x RN
 *                 register tile out of them: every global value is read once per group,
 *                 the GPU shape (CLBlast's xgemm, MNN's and ComputeLibrary's tiled convs).
 *   CONV_LOCAL=0  no local memory and no barrier: each work-item reads its own operands
 *                 from global memory (cache-served), for drivers whose local memory is slow.
 *   CONV_MMA=1|2  tensor cores: a warp (32 work-items along dimension 0) multiplies a
 *                 16 x TN slice with mma.sync m16n8k16 (fp16 in, fp32 accumulate), fed
 *                 from half tiles in local memory. 2: inline PTX, NVIDIA (sm_80+) only;
 *                 1: the same fragments exchanged through local memory and multiplied in
 *                 scalar code, so that every other device checks the data layout the PTX
 *                 instruction sees (the fragment maps of the PTX ISA, "Matrix Fragments
 *                 for mma.m16n8k16"). Half storage (-DCLSS_FP16) only: the tiles copy the
 *                 stored bits, so the products are those of the fp16 reference exactly and
 *                 only the order of the fp32 sums differs.
 *
 * Registers: work-item (tx, ty) owns rows ty + i * WY and columns tx + j * WX of the tile
 * (strided, not blocked), so the lanes of a warp read consecutive X columns from local
 * memory (no bank conflicts) and store consecutive pixels (coalesced).
 *
 * Epilogue as conv2d's (kernels/conv.cl), in conv_epilogue.h: v = acc + bias; + residual
 * before the activation; act; + residual after it. */
#include "common.h"
#include "conv_epilogue.h"   /* store_out: bias, residual, activation */
#include "d2s_index.h"       /* -DD2S: a DepthToSpace fused into the store */

/* Where output channel co (of the group) of pixel p lands: NCHW, or shuffled (d2s_index.h) */
#if D2S
#define Y_AT(co, p) d2s_at(n, g * Cout_g + (co), (p) / Wo, (p) % Wo, Cout, Ho, Wo)
#else
#define Y_AT(co, p) (yoff + (long)(co) * P + (p))
#endif

#ifndef KH
#define KH 3
#endif
#ifndef KW
#define KW 3
#endif
#ifndef TM
#define TM 64
#endif
#ifndef TN
#define TN 64
#endif
#ifndef TK
#define TK 16
#endif
#ifndef RM
#define RM 4
#endif
#ifndef RN
#define RN 4
#endif
#ifndef CONV_LOCAL
#define CONV_LOCAL 1
#endif
#ifndef CONV_MMA
#define CONV_MMA 0
#endif

#define KK (KH * KW)

#if CONV_MMA
#if !defined(CLSS_FP16) || defined(CLSS_FP16_NATIVE)
#error "CONV_MMA needs half storage with float accumulation (-DCLSS_FP16)"
#endif
#if TK % 16 || TN % 8 || TM % 16
#error "CONV_MMA: TK a multiple of 16, TN of 8, TM of 16"
#endif
#define WARPS (TM / 16)          /* one warp per 16 output channels */
#define NT (TN / 8)              /* m16n8 products per warp and k step */
#define NWI (32 * WARPS)
#else
#if TM % RM || TN % RN
#error "TM must be a multiple of RM and TN of RN"
#endif
#define WX (TN / RN)             /* work-items along dimension 0 */
#define WY (TM / RM)             /* work-items along dimension 1 */
#define NWI (WX * WY)
#endif

/* The element of the image/group base under tap k of output pixel p (the im2col matrix
 * X[k, p]), or -1 in the padding and past K or P: written once for both readers below. */
inline long x_at(int k, int p, int K, int P, int H, int W, int Wo,
                 int sy, int sx, int pt, int pl, int dy, int dx)
{
    if (k >= K || p >= P)
        return -1;
    const int ci = k / KK, r = k - ci * KK, ky = r / KW, kx = r - ky * KW;
    const int oy = p / Wo, ox = p - oy * Wo;
    const int iy = oy * sy - pt + ky * dy, ix = ox * sx - pl + kx * dx;
    if (iy < 0 || iy >= H || ix < 0 || ix >= W)
        return -1;
    return ((long)ci * H + iy) * W + ix;
}

/* X[k, p] of image/group base xg, 0 in the padding (never reading outside the input). */
inline A x_col(__global const T *xg, int k, int p, int K, int P, int H, int W, int Wo,
               int sy, int sx, int pt, int pl, int dy, int dx)
{
    const long i = x_at(k, p, K, P, H, W, Wo, sy, sx, pt, pl, dy, dx);
    return i < 0 ? A_ZERO : LD(xg, i);
}

#if CONV_MMA
/* The raw half bits of X[k, p] (0 = +0.0 in the padding): the tiles copy storage. */
inline ushort x_bits(__global const ushort *xg, int k, int p, int K, int P, int H, int W, int Wo,
                     int sy, int sx, int pt, int pl, int dy, int dx)
{
    const long i = x_at(k, p, K, P, H, W, Wo, sy, sx, pt, pl, dy, dx);
    return i < 0 ? (ushort)0 : xg[i];
}

#if CONV_MMA == 2
/* D = A B + C on one warp: A 16x16 row-major, B 16x8 column-major, fp16 pairs per register. */
#define MMA(c, a, b)                                                                          \
    asm volatile("mma.sync.aligned.m16n8k16.row.col.f32.f16.f16.f32 "                       \
                 "{%0,%1,%2,%3}, {%4,%5,%6,%7}, {%8,%9}, {%0,%1,%2,%3};"                      \
                 : "+f"((c)[0]), "+f"((c)[1]), "+f"((c)[2]), "+f"((c)[3])                     \
                 : "r"((a)[0]), "r"((a)[1]), "r"((a)[2]), "r"((a)[3]), "r"((b)[0]), "r"((b)[1]))
#else
/* The same product from the same registers, for devices without the instruction: each lane
 * writes its fragments where the PTX ISA places them (A as [row][k pair], B as [col][k pair]),
 * and each lane then sums the 16 products of its four accumulators. scr: this warp's 192
 * words (A: 16 x 8, B: 8 x 8). Every work-item of the group calls it the same number of
 * times, so the barriers are uniform. */
inline void mma_emulated(__local uint *scr, int lane, float c[4], const uint a[4], const uint b[2])
{
    const int gid = lane >> 2, t = lane & 3;
    __local uint *au = scr, *bu = scr + 128;
    au[gid * 8 + t] = a[0];
    au[(gid + 8) * 8 + t] = a[1];
    au[gid * 8 + t + 4] = a[2];
    au[(gid + 8) * 8 + t + 4] = a[3];
    bu[gid * 8 + t] = b[0];
    bu[gid * 8 + t + 4] = b[1];
    barrier(CLK_LOCAL_MEM_FENCE);
    const __local half *ah = (const __local half *)au, *bh = (const __local half *)bu;
    for (int e = 0; e < 4; ++e) {
        const int row = gid + (e >> 1) * 8, col = 2 * t + (e & 1);
        float s = 0.0f;
        for (int k = 0; k < 16; ++k)
            s += vload_half(row * 16 + k, ah) * vload_half(col * 16 + k, bh);
        c[e] += s;
    }
    barrier(CLK_LOCAL_MEM_FENCE);
}
#define MMA(c, a, b) mma_emulated(scr + warp * 192, lane, (c), (a), (b))
#endif
#endif

/* x: [N, Cin, H, W]; w: [Cout, Cin/groups, KH, KW]; y, res: [N, Cout, Ho, Wo].
 * NDRange (local size in brackets):
 *   CONV_MMA=0: (ceil(Ho*Wo / TN) * WX, ceil(Cout_g / TM) * WY, N * groups), [WX, WY, 1]
 *   CONV_MMA>0: (ceil(Ho*Wo / TN) * 32, ceil(Cout_g / TM) * WARPS, N * groups), [32, WARPS, 1] */
/** @param[in]  x       [N, Cin, H, W] input
 *  @param[in]  w       [Cout, Cin/groups, KH, KW] weights, stored as x
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
 *  @param[in]  groups  groups
 *  @param[in]  sy      stride along y
 *  @param[in]  sx      stride along x
 *  @param[in]  pt      top pad
 *  @param[in]  pl      left pad
 *  @param[in]  dy      dilation along y
 *  @param[in]  dx      dilation along x
 *  @param[in]  flags   1 bias, 2 residual added before the activation, 4 after it
 *  @param[in]  alpha   the activation's parameter (leaky_relu slope)
 *  @note -DKH, -DKW: kernel size; -DTM, -DTN, -DTK: the group's tile; -DRM, -DRN: a work-item's register tile
 *  @note -DCONV_LOCAL=0|1: operands from global memory / staged in local memory; -DACT: the fused activation
 *  @note -DCONV_MMA=0|1|2: scalar FMAs / tensor-core fragments emulated / mma.sync PTX (NVIDIA); 1 and 2 need -DCLSS_FP16
 *  @note -DCLSS_FP16 / -DCLSS_FP16_NATIVE: the storage precision (common.h)
 */
__kernel void conv2d_gemm(__global const T *x, __global const T *w, __global const T *bias,
                          __global const T *res, __global T *y,
                          int Cin, int H, int W, int Cout, int Ho, int Wo, int Cin_g, int Cout_g, int groups,
                          int sy, int sx, int pt, int pl, int dy, int dx, int flags, float alpha)
{
    const int p0 = get_group_id(0) * TN, m0 = get_group_id(1) * TM;
    const int z = get_global_id(2), g = z % groups, n = z / groups;
    const int K = Cin_g * KK, P = Ho * Wo;
    const long xoff = ((long)n * Cin + (long)g * Cin_g) * H * W;
    const long woff = (long)g * Cout_g * K;
    const long yoff = ((long)n * Cout + (long)g * Cout_g) * P;
#if CONV_MMA
    /* Half tiles, rows padded by 8 halves so that the 8 rows a fragment load touches fall in
     * different banks; k pairs are read as one uint (little-endian: the lower k in the low
     * half, as the PTX register holds it). */
    __local ushort ws[TM][TK + 8] __attribute__((aligned(16)));   /* A: [channel][k] */
    __local ushort xs[TN][TK + 8] __attribute__((aligned(16)));   /* B, column-major: [pixel][k] */
#if CONV_MMA == 1
    __local uint scr[WARPS * 192];
#endif
    const int lane = get_local_id(0), warp = get_local_id(1), lid = warp * 32 + lane;
    const int gid = lane >> 2, t = lane & 3;
    const __global ushort *xg = (const __global ushort *)x + xoff;
    const __global ushort *wg = (const __global ushort *)w + woff;
    float acc[NT][4];
    for (int j = 0; j < NT; ++j)
        for (int e = 0; e < 4; ++e)
            acc[j][e] = 0.0f;
    for (int k0 = 0; k0 < K; k0 += TK) {
        for (int e = lid; e < TM * TK; e += NWI) {
            const int mm = e / TK, kk = e - mm * TK, co = m0 + mm, k = k0 + kk;
            ws[mm][kk] = (co < Cout_g && k < K) ? wg[(long)co * K + k] : (ushort)0;
        }
        for (int e = lid; e < TK * TN; e += NWI) {
            const int kk = e / TN, pp = e - kk * TN;
            xs[pp][kk] = x_bits(xg, k0 + kk, p0 + pp, K, P, H, W, Wo, sy, sx, pt, pl, dy, dx);
        }
        barrier(CLK_LOCAL_MEM_FENCE);
        for (int ks = 0; ks < TK; ks += 16) {
            const int r0 = warp * 16 + gid;
            uint a[4];
            a[0] = *(__local const uint *)&ws[r0][ks + 2 * t];
            a[1] = *(__local const uint *)&ws[r0 + 8][ks + 2 * t];
            a[2] = *(__local const uint *)&ws[r0][ks + 2 * t + 8];
            a[3] = *(__local const uint *)&ws[r0 + 8][ks + 2 * t + 8];
            for (int j = 0; j < NT; ++j) {
                uint b[2];
                b[0] = *(__local const uint *)&xs[j * 8 + gid][ks + 2 * t];
                b[1] = *(__local const uint *)&xs[j * 8 + gid][ks + 2 * t + 8];
                MMA(acc[j], a, b);
            }
        }
        barrier(CLK_LOCAL_MEM_FENCE);
    }
    /* c0, c1: row gid, columns 2t, 2t + 1; c2, c3: row gid + 8 */
    for (int e = 0; e < 4; ++e) {
        const int co = m0 + warp * 16 + gid + (e >> 1) * 8;
        if (co >= Cout_g)
            continue;
        const A b = (flags & F_BIAS) ? LD(bias, g * Cout_g + co) : A_ZERO;
        for (int j = 0; j < NT; ++j) {
            const int p = p0 + j * 8 + 2 * t + (e & 1);
            if (p < P)
                store_out(y, res, Y_AT(co, p), acc[j][e], b, flags, alpha);
        }
    }
#else
    const int tx = get_local_id(0), ty = get_local_id(1);
    const __global T *xg = x + xoff;
    const __global T *wg = w + woff;
    A acc[RM][RN];
    for (int i = 0; i < RM; ++i)
        for (int j = 0; j < RN; ++j)
            acc[i][j] = A_ZERO;
#if CONV_LOCAL
    /* ws transposed ([k][channel]): a work-item's RM weights of one k are one row. */
    __local A ws[TK][TM];
    __local A xs[TK][TN];
    const int lid = ty * WX + tx;
    for (int k0 = 0; k0 < K; k0 += TK) {
        for (int e = lid; e < TM * TK; e += NWI) {
            const int mm = e / TK, kk = e - mm * TK, co = m0 + mm, k = k0 + kk;
            ws[kk][mm] = (co < Cout_g && k < K) ? LD(wg, (long)co * K + k) : A_ZERO;
        }
        for (int e = lid; e < TK * TN; e += NWI) {
            const int kk = e / TN, pp = e - kk * TN;
            xs[kk][pp] = x_col(xg, k0 + kk, p0 + pp, K, P, H, W, Wo, sy, sx, pt, pl, dy, dx);
        }
        barrier(CLK_LOCAL_MEM_FENCE);
        for (int kk = 0; kk < TK; ++kk) {
            A a[RM], b[RN];
            for (int i = 0; i < RM; ++i)
                a[i] = ws[kk][ty + i * WY];
            for (int j = 0; j < RN; ++j)
                b[j] = xs[kk][tx + j * WX];
            for (int i = 0; i < RM; ++i)
                for (int j = 0; j < RN; ++j)
                    acc[i][j] += a[i] * b[j];
        }
        barrier(CLK_LOCAL_MEM_FENCE);
    }
#else
    for (int k = 0; k < K; ++k) {
        A a[RM], b[RN];
        for (int i = 0; i < RM; ++i) {
            const int co = m0 + ty + i * WY;
            a[i] = co < Cout_g ? LD(wg, (long)co * K + k) : A_ZERO;
        }
        for (int j = 0; j < RN; ++j)
            b[j] = x_col(xg, k, p0 + tx + j * WX, K, P, H, W, Wo, sy, sx, pt, pl, dy, dx);
        for (int i = 0; i < RM; ++i)
            for (int j = 0; j < RN; ++j)
                acc[i][j] += a[i] * b[j];
    }
#endif
    for (int i = 0; i < RM; ++i) {
        const int co = m0 + ty + i * WY;
        if (co >= Cout_g)
            continue;
        const A b = (flags & F_BIAS) ? LD(bias, g * Cout_g + co) : A_ZERO;
        for (int j = 0; j < RN; ++j) {
            const int p = p0 + tx + j * WX;
            if (p < P)
                store_out(y, res, Y_AT(co, p), acc[i][j], b, flags, alpha);
        }
    }
#endif
}
