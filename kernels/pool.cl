/* Pooling: windowed max / average (1-3 spatial dims) and global max / average.
 *
 * Build options:
 *   -DMODE=0     max (selects a stored value: bit-exact in every precision)
 *   -DMODE=1     average (float accumulation; fp16-native accumulates in half)
 *   -DCOUNT_PAD=1  average divides by the taps inside the padded extent
 *                  [-pad_begin, in + pad_end) (ONNX count_include_pad=1);
 *                  0 divides by the taps inside the input.
 *   -DINDICES=1  max also writes the flat NCHW index of each maximum (int64)
 *   -DCHUNK=n    global pooling: elements one work-item reduces in pass 1
 *   -DFINAL=1    global pooling with a single chunk per row: pass 1 writes the
 *                result directly and pass 2 is skipped
 *   -DGLOBAL_LANES=8 (default) global pooling pass 1 accumulates in 8 vector lanes
 *                (the fast path); =1 one scalar accumulator (the portable reference
 *                of the fast-path self-check)
 *
 *   -DCLSS_CLANG_VECTORS=1  max_pool_row8's and global pooling's 8-wide loads and
 *                stores as clang vectors (common.h FLD8/FST8; else vload8/vload_half8).
 *                Global pooling needs it on PoCL: PoCL 3.1 and 5.0 built for
 *                skylake-avx512 crash (SIGSEGV) on vload_half8 from a row that does
 *                not start on a 16-byte boundary (HW % 8 != 0), an alignment OpenCL
 *                does not require of vload_half8.
 *
 * A 2-D tensor is pooled as 3-D with depth 1, so one kernel serves
 * MaxPool/AveragePool over 1, 2 and 3 spatial dimensions.
 */
#include "common.h"

#ifndef MODE
#define MODE 0
#endif
#ifndef COUNT_PAD
#define COUNT_PAD 0
#endif
#ifndef INDICES
#define INDICES 0
#endif
#ifndef CHUNK
#define CHUNK 2048
#endif
#ifndef GLOBAL_LANES
#define GLOBAL_LANES 8
#endif
#ifndef FINAL
#define FINAL 0
#endif

/* First and last tap k in [0, K) with lo <= start + k*dil < hi; empty when k1 < k0.
 * Counting taps in closed form keeps bounds checks out of the inner loops and
 * makes the average's divisor a product of three per-axis counts. */
inline int2 tap_range(int start, int K, int dil, int lo, int hi)
{
    const int k0 = start >= lo ? 0 : (lo - start + dil - 1) / dil;
    const int k1 = start > hi - 1 ? -1 : min(K - 1, (hi - 1 - start) / dil);
    return (int2)(k0, k1);
}

/* in: [NC, ID, IH, IW] -> out: [NC, OD, OH, OW]; NDRange (OW, OH, NC*OD).
 * P* are the begin pads, E* = in + end pad (the padded extent, for COUNT_PAD). */
/** @param[in]  in          [NC, ID, IH, IW] input (2-D pooling: ID = 1)
 *  @param[out] out         [NC, OD, OH, OW] output
 *  @param[out] indices     (-DINDICES=1 only) [NC, OD, OH, OW] flat index of each maximum
 *  @param[in]  column_major (-DINDICES=1 only) ONNX storage_order = 1: indices counted column-major
 *  @param[in]  ID, IH, IW  input depth, height, width
 *  @param[in]  OD, OH, OW  output depth, height, width
 *  @param[in]  KD, KH, KW  window size
 *  @param[in]  SD, SH, SW  strides
 *  @param[in]  PD, PH, PW  begin pads
 *  @param[in]  DD, DH, DW  dilations
 *  @param[in]  ED, EH, EW  input size + end pad (the padded extent, for COUNT_PAD)
 *  @param[in]  NCOD        NC * OD, the extent of NDRange dimension 2
 *  @note -DMODE=0|1: max | average; -DCOUNT_PAD=0|1; -DINDICES=0|1
 *  @note -DCLSS_FP16 / -DCLSS_FP16_NATIVE: the storage precision (common.h); T and TB follow it
 */
__kernel void pool(__global const T *in, __global T *out,
#if INDICES
                   __global long *indices, int column_major,
#endif
                   int ID, int IH, int IW, int OD, int OH, int OW,
                   int KD, int KH, int KW, int SD, int SH, int SW,
                   int PD, int PH, int PW, int DD, int DH, int DW,
                   int ED, int EH, int EW, int NCOD)
{
    const int ox = get_global_id(0), oy = get_global_id(1), z = get_global_id(2);
    if (ox >= OW || oy >= OH || z >= NCOD) return;
    const int nc = z / OD, od = z % OD;
    const int d0 = od * SD - PD, h0 = oy * SH - PH, w0 = ox * SW - PW;
    const int2 kd = tap_range(d0, KD, DD, 0, ID);
    const int2 kh = tap_range(h0, KH, DH, 0, IH);
    const int2 kw = tap_range(w0, KW, DW, 0, IW);
    const long base = (long)nc * ID * IH * IW;
    const long o = ((long)z * OH + oy) * OW + ox;
#if MODE == 0
    A m = (A)(-INFINITY);
#if INDICES
    long arg = -1;
#endif
    for (int i = kd.x; i <= kd.y; ++i) {
        const int d = d0 + i * DD;
        for (int j = kh.x; j <= kh.y; ++j) {
            const int h = h0 + j * DH;
            const long row = base + ((long)d * IH + h) * IW;
            for (int k = kw.x; k <= kw.y; ++k) {
                const int w = w0 + k * DW;
                const A v = LD(in, row + w);
                /* strict > keeps the first maximum, as onnxruntime does */
                if (v > m) {
                    m = v;
#if INDICES
                    arg = column_major ? base + (long)w * IH + h : row + w;
#endif
                }
            }
        }
    }
    ST(out, o, m);
#if INDICES
    indices[o] = arg;
#endif
#else
    A s = A_ZERO;
    for (int i = kd.x; i <= kd.y; ++i) {
        const int d = d0 + i * DD;
        for (int j = kh.x; j <= kh.y; ++j) {
            const long row = base + ((long)d * IH + h0 + j * DH) * IW;
            for (int k = kw.x; k <= kw.y; ++k)
                s += LD(in, row + w0 + k * DW);
        }
    }
#if COUNT_PAD
    const int2 cd = tap_range(d0, KD, DD, -PD, ED);
    const int2 ch = tap_range(h0, KH, DH, -PH, EH);
    const int2 cw = tap_range(w0, KW, DW, -PW, EW);
#else
    const int2 cd = kd, ch = kh, cw = kw;
#endif
    const int count = (cd.y - cd.x + 1) * (ch.y - ch.x + 1) * (cw.y - cw.x + 1);
    ST(out, o, s / (A)count);
#endif
}

/* 2-D max pooling with a window 3 wide, stride and dilation 1 along x, no
 * indices: the host's fast path (POOL_ROW8=1 in clss/ops/pool.py; `pool` is its
 * reference). Eight outputs along x per work-item: per window row one load of
 * the 10 inputs they see, the three taps as shifted vectors. Taps are visited
 * in the reference's order with its strict `>` (the first maximum wins, NaN is
 * never selected), so the result is the same stored value; inputs outside the
 * row read as -inf, which `>` never selects.
 * in: [NC, IH, IW] -> out: [NC, OH, OW]; NDRange (ceil(OW / 8), OH, NC). */
#ifndef POOL_ROWS
#define POOL_ROWS 1
#endif

/* The strict-`>` maximum of window columns 0, 1, 2 of one input row for the 8
 * outputs from w0 on, visited in the reference's order; -inf outside the row. */
inline A8 row_max8(const __global T *row, int w0, int IW, int inside)
{
    A8 a;
    A b0, b1;
    if (inside) {
        a = FLD8(row, w0);
        b0 = FLD(row, w0 + 8);
        b1 = FLD(row, w0 + 9);
    } else {
        union { A8 v; A e[8]; } u;
        for (int e = 0; e < 8; ++e) {
            const int p = w0 + e;
            u.e[e] = (p >= 0 && p < IW) ? FLD(row, p) : (A)(-INFINITY);
        }
        a = u.v;
        b0 = (w0 + 8 >= 0 && w0 + 8 < IW) ? FLD(row, w0 + 8) : (A)(-INFINITY);
        b1 = (w0 + 9 >= 0 && w0 + 9 < IW) ? FLD(row, w0 + 9) : (A)(-INFINITY);
    }
    const A8 t1 = (A8)(a.s123, a.s4567, b0);
    const A8 t2 = (A8)(a.s23, a.s4567, b0, b1);
    A8 h = (A8)(-INFINITY);
    h = a > h ? a : h;
    h = t1 > h ? t1 : h;
    h = t2 > h ? t2 : h;
    return h;
}

inline void store_row8(__global T *o, int n, A8 m)
{
    if (n >= 8) {
        FST8(o, 0, m);
    } else {
        union { A8 v; A e[8]; } u;
        u.v = m;
        for (int e = 0; e < n; ++e)
            FST(o, e, u.e[e]);
    }
}

/* Row maxima first, then the maximum over the window's rows: with the strict `>`
 * in both, the first maximum in row-major order wins, as in the reference.
 * -DPOOL_ROWS=R > 1 (host: only for unit stride and dilation along y): R output
 * rows per work-item share the R + KH - 1 row maxima they need, each input row
 * read and reduced once instead of KH times. */
/** @param[in]  in   [NC, IH, IW] input
 *  @param[out] out  [NC, OH, OW] output
 *  @param[in]  IH   input height
 *  @param[in]  IW   input width
 *  @param[in]  OH   output height
 *  @param[in]  OW   output width
 *  @param[in]  KH   window height (the width is 3)
 *  @param[in]  SH   stride along y (1 when POOL_ROWS > 1)
 *  @param[in]  PH   begin pad along y
 *  @param[in]  PW   begin pad along x
 *  @param[in]  DH   dilation along y (1 when POOL_ROWS > 1)
 *  @param[in]  NC   N * C, the extent of NDRange dimension 2
 *  @note -DMODE=0 only; -DCLSS_CLANG_VECTORS=0|1: builtin-free loads and stores
 *  @note -DPOOL_ROWS=R: output rows per work-item (NDRange (ceil(OW / 8), ceil(OH / R), NC))
 *  @note -DCLSS_FP16 / -DCLSS_FP16_NATIVE: the storage precision (common.h); T and TB follow it
 */
__kernel void max_pool_row8(__global const T *in, __global T *out, int IH, int IW, int OH, int OW,
                            int KH, int SH, int PH, int PW, int DH, int NC)
{
    const int ox0 = get_global_id(0) * 8, oy0 = get_global_id(1) * POOL_ROWS, nc = get_global_id(2);
    if (ox0 >= OW || oy0 >= OH || nc >= NC) return;
    const int w0 = ox0 - PW;
    const __global T *base = in + (long)nc * IH * IW;
    const int inside = w0 >= 0 && w0 + 10 <= IW;
    __global T *o = out + ((long)nc * OH + oy0) * OW + ox0;
#if POOL_ROWS == 1
    const int h0 = oy0 * SH - PH;
    const int2 kh = tap_range(h0, KH, DH, 0, IH);
    A8 m = (A8)(-INFINITY);
    for (int j = kh.x; j <= kh.y; ++j) {
        const A8 h = row_max8(base + (long)(h0 + j * DH) * IW, w0, IW, inside);
        m = h > m ? h : m;
    }
    store_row8(o, OW - ox0, m);
#else
    A8 m[POOL_ROWS];
#pragma unroll
    for (int r = 0; r < POOL_ROWS; ++r)
        m[r] = (A8)(-INFINITY);
    const int y0 = oy0 - PH;
    for (int i = 0; i < POOL_ROWS + KH - 1; ++i) {
        const int y = y0 + i;
        if (y < 0 || y >= IH)
            continue;
        const A8 h = row_max8(base + (long)y * IW, w0, IW, inside);
#pragma unroll
        for (int r = 0; r < POOL_ROWS; ++r) {
            const int j = i - r;     /* window row of input row y for output row oy0 + r */
            if (j >= 0 && j < KH)
                m[r] = h > m[r] ? h : m[r];
        }
    }
#pragma unroll
    for (int r = 0; r < POOL_ROWS; ++r)
        if (oy0 + r < OH)
            store_row8(o + (long)r * OW, OW - ox0, m[r]);
#endif
}

/* 2x2 windows at stride 2, no padding, dilation 1, floor output (the U-Nets' down-sampling):
 * 8 outputs of a row per work-item from two rows of 16 inputs, their even and odd lanes,
 * taken in the reference's order (row by row, left to right, strict `>`).
 * @param[in]  in   [NC, IH, IW] input
 * @param[out] out  [NC, OH, OW] output (OH = IH / 2, OW = IW / 2)
 * @param[in]  IH   input height
 * @param[in]  IW   input width
 * @param[in]  OH   output height
 * @param[in]  OW   output width
 * @param[in]  NC   N * C, the extent of NDRange dimension 2
 * @note NDRange (ceil(OW / 8), OH, NC); -DCLSS_CLANG_VECTORS=0|1: builtin-free loads/stores */
__kernel void max_pool_2x2(__global const T *in, __global T *out, int IH, int IW, int OH, int OW,
                           int NC)
{
    const int ox0 = get_global_id(0) * 8, oy = get_global_id(1), nc = get_global_id(2);
    if (ox0 >= OW || oy >= OH || nc >= NC) return;
    const __global T *r0 = in + ((long)nc * IH + 2 * oy) * IW + 2 * ox0;
    const __global T *r1 = r0 + IW;
    A8 m = (A8)(-INFINITY);
    if (2 * ox0 + 16 <= IW) {
        const A8 a0 = FLD8(r0, 0), a1 = FLD8(r0, 8), b0 = FLD8(r1, 0), b1 = FLD8(r1, 8);
        const A8 t00 = (A8)(a0.even, a1.even), t01 = (A8)(a0.odd, a1.odd);
        const A8 t10 = (A8)(b0.even, b1.even), t11 = (A8)(b0.odd, b1.odd);
        m = t00 > m ? t00 : m;
        m = t01 > m ? t01 : m;
        m = t10 > m ? t10 : m;
        m = t11 > m ? t11 : m;
    } else {
        union { A8 v; A e[8]; } u;
        u.v = m;
        for (int e = 0; e < 8 && ox0 + e < OW; ++e) {
            const A t[4] = {FLD(r0, 2 * e), FLD(r0, 2 * e + 1), FLD(r1, 2 * e), FLD(r1, 2 * e + 1)};
            for (int q = 0; q < 4; ++q)
                u.e[e] = t[q] > u.e[e] ? t[q] : u.e[e];
        }
        m = u.v;
    }
    store_row8(out + ((long)nc * OH + oy) * OW + ox0, OW - ox0, m);
}

/* max_pool_2x2 on the channel-blocked layout [N][Cb][H][W][BLK] (clss/model/layout.py):
 * a work-item is one output pixel's block of BLK channels (-DBLK=8|16, the block), as one
 * vector; the same four taps in the same order and the same strict `>` per lane as
 * max_pool_2x2, so the two agree bit for bit. A block is BLK-aligned in the buffer.
 * @param[in]  in   [NCb, IH, IW, BLK] input
 * @param[out] out  [NCb, OH, OW, BLK] output (OH = IH / 2, OW = IW / 2)
 * @param[in]  IH   input height
 * @param[in]  IW   input width
 * @param[in]  OH   output height
 * @param[in]  OW   output width
 * @param[in]  NCB  N * Cb, the extent of NDRange dimension 2
 * @note NDRange (OW, OH, NCB); -DBLK=8|16 */
#ifndef BLK
#define BLK 16
#endif
#if BLK == 16
typedef float16 FB;
#define LDH_B vload_half16
#define STH_B vstore_half16_rte
#elif BLK == 8
typedef float8 FB;
#define LDH_B vload_half8
#define STH_B vstore_half8_rte
#else
#error "BLK must be 8 or 16"
#endif
#if defined(CLSS_FP16) && BLK == 16
/* as two 8-lane halves: pip's PoCL 3.0 (LLVM 14) on an AVX-512 EPYC aborted compiling
 * vstore_half16_rte ("Do not know how to split this operator's operand!"); the halves are the
 * same bits on every compiler */
#define LD_B(p, k) ((FB)(vload_half8(2 * (k), (p)), vload_half8(2 * (k) + 1, (p))))
#define ST_B(p, k, v) (vstore_half8_rte((v).lo, 2 * (k), (p)), vstore_half8_rte((v).hi, 2 * (k) + 1, (p)))
typedef FB AB;
#elif defined(CLSS_FP16)
#define LD_B(p, k) LDH_B((k), (p))
#define ST_B(p, k, v) STH_B((v), (k), (p))
typedef FB AB;
#else
#define LD_B(p, k) (((__global const AB *)(p))[k])
#define ST_B(p, k, v) (((__global AB *)(p))[k] = (v))
#if defined(CLSS_FP16_NATIVE)
#if BLK == 16
typedef half16 AB;
#else
typedef half8 AB;
#endif
#else
typedef FB AB;
#endif
#endif
__kernel void max_pool_2x2_blocked(__global const T *in, __global T *out, int IH, int IW, int OH,
                                   int OW, int NCB)
{
    const int ox = get_global_id(0), oy = get_global_id(1), z = get_global_id(2);
    if (ox >= OW || oy >= OH || z >= NCB) return;
    const long r0 = ((long)z * IH + 2 * oy) * IW + 2 * ox, r1 = r0 + IW;
    const AB t00 = LD_B(in, r0), t01 = LD_B(in, r0 + 1), t10 = LD_B(in, r1), t11 = LD_B(in, r1 + 1);
    AB m = (AB)(-INFINITY);
    m = t00 > m ? t00 : m;
    m = t01 > m ? t01 : m;
    m = t10 > m ? t10 : m;
    m = t11 > m ? t11 : m;
    ST_B(out, ((long)z * OH + oy) * OW + ox, m);
}

/* Global pooling, pass 1: one work-item reduces CHUNK contiguous elements of
 * one row (NDRange (nchunks, NC)); eight lanes accumulate side by side, which
 * is both the vector load and a first level of pairwise summation. */
#if MODE == 0
#define COMBINE(a, b) fmax((a), (b))
#define INIT ((A)(-INFINITY))
#else
#define COMBINE(a, b) ((a) + (b))
#define INIT A_ZERO
#endif

/** @param[in]  in       [NC, HW] input rows
 *  @param[out] out      (-DFINAL=1 only) [NC] the result, when one chunk covers a row
 *  @param[out] part     (-DFINAL=0 only) [NC, nchunks] float partial results
 *  @param[in]  HW       elements per row
 *  @param[in]  nchunks  chunks per row (NDRange dimension 0)
 *  @param[in]  NC       rows (NDRange dimension 1)
 *  @param[in]  count    the average's divisor (HW)
 *  @note -DMODE=0|1: max | average; -DCHUNK=n; -DFINAL=0|1; -DGLOBAL_LANES=8|1 (fast path | reference)
 *  @note -DCLSS_FP16 / -DCLSS_FP16_NATIVE: the storage precision (common.h); T and TB follow it
 */
__kernel void global_pool_partial(__global const T *in,
#if FINAL
                                  __global T *out,
#else
                                  __global float *part,
#endif
                                  int HW, int nchunks, int NC, float count)
{
    const int chunk = get_global_id(0), nc = get_global_id(1);
    if (chunk >= nchunks || nc >= NC) return;
    const int lo = chunk * CHUNK, hi = min(HW, lo + CHUNK);
    __global const T *p = in + (long)nc * HW;
    int i = lo;
#if GLOBAL_LANES == 8
    A8 acc = (A8)INIT;
    for (; i + 8 <= hi; i += 8)
        acc = COMBINE(acc, FLD8(p, i));   /* element-aligned: see -DCLSS_CLANG_VECTORS */
    A4 a4 = COMBINE(acc.lo, acc.hi);
    A r = COMBINE(COMBINE(a4.x, a4.y), COMBINE(a4.z, a4.w));
#else
    A r = INIT;
#endif
    for (; i < hi; ++i)
        r = COMBINE(r, LD(p, i));
#if FINAL
#if MODE == 1
    r = (A)((float)r / count);
#endif
    ST(out, nc, r);
#else
    part[(long)nc * nchunks + chunk] = (float)r;
#endif
}

/* Global pooling, pass 2: one work-item per row combines its chunk results. */
/** @param[in]  part     [NC, nchunks] the partial results of pass 1
 *  @param[out] out      [NC] output
 *  @param[in]  nchunks  chunks per row
 *  @param[in]  NC       rows
 *  @param[in]  count    the average's divisor
 *  @note -DMODE=0|1: max | average
 *  @note -DCLSS_FP16 / -DCLSS_FP16_NATIVE: the storage precision (common.h); T and TB follow it
 */
__kernel void global_pool_final(__global const float *part, __global T *out,
                                int nchunks, int NC, float count)
{
    const int nc = get_global_id(0);
    if (nc >= NC) return;
    __global const float *p = part + (long)nc * nchunks;
    A r = INIT;
    for (int i = 0; i < nchunks; ++i)
        r = COMBINE(r, (A)p[i]);
#if MODE == 1
    r = (A)((float)r / count);
#endif
    ST(out, nc, r);
}
