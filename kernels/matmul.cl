/* Matrix products of two run-time tensors: ONNX MatMul (batched, broadcasting) and Gemm
 * (alpha, beta, transposes, C broadcast), as attention uses them (Q K^T, softmax(.) V).
 * A MatMul or Gemm with a constant B never comes here: clss.Model lowers it to a 1x1
 * convolution (clss/model/passes.py), which has the conv family's fast paths.
 *
 *   out[b, m, n] = alpha * sum_k A[b, m, k] * B[b, k, n] + beta * C[m, n]
 *
 * Every operand is read through element strides, so a transposed or broadcast operand
 * needs no copy: A at a_b0*b0 + a_b1*b1 + a_m*m + a_k*k, B likewise, C at c_m*m + c_n*n
 * (0 along a broadcast axis). Up to two batch dimensions [B0, B1].
 *
 * A work-item computes a TM x TN tile of one batch (TM rows of A times TN columns of B:
 * TM + TN loads per TM * TN multiply-adds), NDRange (ceil(N / TN), ceil(M / TM), B0 * B1).
 * Edge tiles clamp their reads and skip their stores.
 *
 * Build options:
 *   -DTM=n, -DTN=n   the register tile (default 4 x 4)
 *   -DCLSS_CLANG_VECTORS=0|1  the fast kernels' loads as clang vector accesses (PoCL)
 *   -DHAS_C=0|1      add beta * C
 */
#include "common.h"

#ifndef TM
#define TM 4
#endif
#ifndef TN
#define TN 4
#endif
#ifndef HAS_C
#define HAS_C 0
#endif

/* What `matmul` and `matmul_k8` begin with: this work-item's tile (rows m0.., columns
 * n0..) of batch z, the batch's A and B, and each tile row's and column's offset (edge
 * tiles clamp their reads to the last row or column). */
#define TILE_PROLOGUE                                                               \
    const int n0 = get_global_id(0) * TN, m0 = get_global_id(1) * TM, z = get_global_id(2); \
    if (n0 >= N || m0 >= M) return;                                                \
    const int z0 = z / B1, z1 = z % B1;                                             \
    __global const T *pa = a + z0 * a_b0 + z1 * a_b1;                               \
    __global const T *pb = b + z0 * b_b0 + z1 * b_b1;                               \
    long ra[TM], cb[TN];                                                            \
    for (int i = 0; i < TM; ++i)                                                    \
        ra[i] = (long)min(m0 + i, M - 1) * a_m;                                     \
    for (int j = 0; j < TN; ++j)                                                    \
        cb[j] = (long)min(n0 + j, N - 1) * b_n;

/** @param[in]  a       A
 *  @param[in]  b       B
 *  @param[in]  c       C (read with -DHAS_C=1)
 *  @param[out] out     [B0, B1, M, N] the product (contiguous)
 *  @param[in]  M, N, K  the product's sizes
 *  @param[in]  B1      the second batch dimension (B0 * B1 is NDRange dimension 2)
 *  @param[in]  a_b0, a_b1, a_m, a_k  A's element strides (0 where A broadcasts)
 *  @param[in]  b_b0, b_b1, b_k, b_n  B's element strides
 *  @param[in]  c_m, c_n  C's element strides
 *  @param[in]  alpha, beta  Gemm's scales (1 and 0 for MatMul)
 *  @note -DTM=n, -DTN=n: the register tile; -DHAS_C=0|1
 *  @note -DCLSS_FP16 / -DCLSS_FP16_NATIVE: the storage precision (common.h); T and TB follow it
 */
__kernel void matmul(__global const T *a, __global const T *b, __global const T *c, __global T *out,
                     int M, int N, int K, int B1, long a_b0, long a_b1, long a_m, long a_k,
                     long b_b0, long b_b1, long b_k, long b_n, long c_m, long c_n,
                     float alpha, float beta)
{
    TILE_PROLOGUE
    float acc[TM][TN];
    for (int i = 0; i < TM; ++i)
        for (int j = 0; j < TN; ++j)
            acc[i][j] = 0.0f;
    for (int k = 0; k < K; ++k) {
        float av[TM], bv[TN];
        for (int i = 0; i < TM; ++i)
            av[i] = (float)LD(pa, ra[i] + k * a_k);
        for (int j = 0; j < TN; ++j)
            bv[j] = (float)LD(pb, cb[j] + k * b_k);
        for (int i = 0; i < TM; ++i)
            for (int j = 0; j < TN; ++j)
                acc[i][j] = fma(av[i], bv[j], acc[i][j]);
    }
    __global T *po = out + (long)z * M * N;
    for (int i = 0; i < TM; ++i) {
        const int m = m0 + i;
        if (m >= M) break;
        for (int j = 0; j < TN; ++j) {
            const int n = n0 + j;
            if (n >= N) break;
            float v = alpha * acc[i][j];
#if HAS_C
            v += beta * (float)LD(c, m * c_m + n * c_n);
#endif
            ST(po, (long)m * N + n, v);
        }
    }
}

/* matmul for a B whose columns are contiguous (b_n == 1, N >= 8): a work-item computes TM
 * rows x 8 columns, each k one 8-wide load of B's row and TM scalar loads of A, 8 * TM
 * multiply-adds; a row's last columns short of 8 one by one. The host's fast path
 * (matmul.vectors in clss/ops/matmul.py; `matmul` is its reference). Same arguments; NDRange (ceil(N / 8), ceil(M / TM), B0 * B1). */
/** @param[in]  a       A
 *  @param[in]  b       B (b_n == 1)
 *  @param[in]  c       C (read with -DHAS_C=1)
 *  @param[out] out     [B0, B1, M, N] the product (contiguous)
 *  @param[in]  M, N, K  the product's sizes
 *  @param[in]  B1      the second batch dimension (B0 * B1 is NDRange dimension 2)
 *  @param[in]  a_b0, a_b1, a_m, a_k  A's element strides (0 where A broadcasts)
 *  @param[in]  b_b0, b_b1, b_k, b_n  B's element strides
 *  @param[in]  c_m, c_n  C's element strides
 *  @param[in]  alpha, beta  Gemm's scales (1 and 0 for MatMul)
 *  @note -DTM=n: rows per work-item; -DHAS_C=0|1; -DCLSS_CLANG_VECTORS=0|1
 *  @note -DCLSS_FP16 / -DCLSS_FP16_NATIVE: the storage precision (common.h); T and TB follow it
 */
__kernel void matmul_n8(__global const T *a, __global const T *b, __global const T *c, __global T *out,
                        int M, int N, int K, int B1, long a_b0, long a_b1, long a_m, long a_k,
                        long b_b0, long b_b1, long b_k, long b_n, long c_m, long c_n,
                        float alpha, float beta)
{
    const int n0 = get_global_id(0) * 8, m0 = get_global_id(1) * TM, z = get_global_id(2);
    if (n0 >= N || m0 >= M) return;
    const int z0 = z / B1, z1 = z % B1;
    __global const T *pa = a + z0 * a_b0 + z1 * a_b1;
    __global const T *pb = b + z0 * b_b0 + z1 * b_b1;
    long ra[TM];
    for (int i = 0; i < TM; ++i)
        ra[i] = (long)min(m0 + i, M - 1) * a_m;
    __global T *po = out + (long)z * M * N;
    if (n0 + 8 > N) {           /* the row's ragged end: column by column */
        for (int i = 0; i < TM && m0 + i < M; ++i)
            for (int n = n0; n < N; ++n) {
                float s = 0.0f;
                for (int k = 0; k < K; ++k)
                    s = fma((float)FLD(pa, ra[i] + k * a_k), (float)FLD(pb, k * b_k + n), s);
                float v = alpha * s;
#if HAS_C
                v += beta * (float)LD(c, (m0 + i) * c_m + n * c_n);
#endif
                FST(po, (long)(m0 + i) * N + n, v);
            }
        return;
    }
    const int nb = n0;
    float8 acc[TM];
    for (int i = 0; i < TM; ++i)
        acc[i] = (float8)(0.0f);
    for (int k = 0; k < K; ++k) {
        const float8 bv = convert_float8(FLD8(pb, k * b_k + nb));
        for (int i = 0; i < TM; ++i)
            acc[i] = fma((float8)((float)FLD(pa, ra[i] + k * a_k)), bv, acc[i]);
    }
    for (int i = 0; i < TM; ++i) {
        const int m = m0 + i;
        if (m >= M) break;
        float8 v = alpha * acc[i];
#if HAS_C
        for (int j = 0; j < 8; ++j)
            ((float *)&v)[j] += beta * (float)LD(c, m * c_m + (nb + j) * c_n);
#endif
        FST8(po, (long)m * N + nb, CONVERT_A8(v));
    }
}

/* matmul where A's rows and B's columns both run along k in memory (a_k == b_k == 1:
 * Gemm with transB, Q K^T read without its transpose, K >= 8): a work-item computes TM x TN
 * outputs as dot products of 8-wide loads. The host's fast path (matmul.vectors;
 * `matmul` is its reference). Same arguments; NDRange (ceil(N / TN), ceil(M / TM), B0 * B1). */
/** @param[in]  a       A (a_k == 1)
 *  @param[in]  b       B (b_k == 1)
 *  @param[in]  c       C (read with -DHAS_C=1)
 *  @param[out] out     [B0, B1, M, N] the product (contiguous)
 *  @param[in]  M, N, K  the product's sizes
 *  @param[in]  B1      the second batch dimension (B0 * B1 is NDRange dimension 2)
 *  @param[in]  a_b0, a_b1, a_m, a_k  A's element strides (0 where A broadcasts)
 *  @param[in]  b_b0, b_b1, b_k, b_n  B's element strides
 *  @param[in]  c_m, c_n  C's element strides
 *  @param[in]  alpha, beta  Gemm's scales (1 and 0 for MatMul)
 *  @note -DTM=n, -DTN=n: the register tile; -DHAS_C=0|1; -DCLSS_CLANG_VECTORS=0|1
 *  @note -DCLSS_FP16 / -DCLSS_FP16_NATIVE: the storage precision (common.h); T and TB follow it
 */
__kernel void matmul_k8(__global const T *a, __global const T *b, __global const T *c, __global T *out,
                        int M, int N, int K, int B1, long a_b0, long a_b1, long a_m, long a_k,
                        long b_b0, long b_b1, long b_k, long b_n, long c_m, long c_n,
                        float alpha, float beta)
{
    TILE_PROLOGUE
    float8 acc[TM][TN];
    for (int i = 0; i < TM; ++i)
        for (int j = 0; j < TN; ++j)
            acc[i][j] = (float8)(0.0f);
    int k = 0;
    for (; k + 8 <= K; k += 8) {
        float8 av[TM], bv[TN];
        for (int i = 0; i < TM; ++i)
            av[i] = convert_float8(FLD8(pa, ra[i] + k));
        for (int j = 0; j < TN; ++j)
            bv[j] = convert_float8(FLD8(pb, cb[j] + k));
        for (int i = 0; i < TM; ++i)
            for (int j = 0; j < TN; ++j)
                acc[i][j] = fma(av[i], bv[j], acc[i][j]);
    }
    __global T *po = out + (long)z * M * N;
    for (int i = 0; i < TM; ++i) {
        const int m = m0 + i;
        if (m >= M) break;
        for (int j = 0; j < TN; ++j) {
            const int n = n0 + j;
            if (n >= N) break;
            const float8 s8 = acc[i][j];
            float s = ((s8.s0 + s8.s1) + (s8.s2 + s8.s3)) + ((s8.s4 + s8.s5) + (s8.s6 + s8.s7));
            for (int kk = k; kk < K; ++kk)
                s = fma((float)FLD(pa, ra[i] + kk), (float)FLD(pb, cb[j] + kk), s);
            float v = alpha * s;
#if HAS_C
            v += beta * (float)LD(c, m * c_m + n * c_n);
#endif
            FST(po, (long)m * N + n, v);
        }
    }
}
