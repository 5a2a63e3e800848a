/* The SMPTE ST 2084 (PQ) transfer of clss.pipeline.contract, one pixel value at a time,
 * for the frame steps whose colour lives in PQ (nsrr.cl, nsrd.cl): linear * pq_scale
 * (nits / 10000) in, [0, 1] out, and back (inv_pq_scale = 10000 / nits). frame.cl has
 * its own vector form (common.h's HDR transfer). */
#ifndef CLSS_PQ_H
#define CLSS_PQ_H

/* x^y for x >= 0 as exp2(y log2 x): PoCL's pow() is a library call of ~0.25 us, which made
 * the PQ decode of a 1080p frame take 2.6 s; exp2/log2 inline and agree to a few ulp. */
static float powp(float x, float y)
{
    return x > 0.0f ? exp2(y * log2(x)) : 0.0f;
}

static float pq_encode(float x, float pq_scale)
{
    const float y = clamp(x * pq_scale, 0.0f, 1.0f);
    const float ym = powp(y, 0.1593017578125f);
    return powp((0.8359375f + 18.8515625f * ym) / (1.0f + 18.6875f * ym), 78.84375f);
}

static float pq_decode(float e, float inv_pq_scale)
{
    const float ep = powp(clamp(e, 0.0f, 1.0f), 1.0f / 78.84375f);
    const float num = max(ep - 0.8359375f, 0.0f);
    return powp(num / (18.8515625f - 18.6875f * ep), 1.0f / 0.1593017578125f) * inv_pq_scale;
}

/* pq_decode on 8 values at once: the same operations lane by lane. Scalar exp2/log2 are
 * library calls on PoCL (about 0.2 us a decode: 1.3 s of a 1080p frame); on float8 they
 * vectorise. */
static float8 powp8(float8 x, float y)
{
    return select((float8)(0.0f), exp2(y * log2(x)), x > 0.0f);
}

static float8 pq_decode8(float8 e, float inv_pq_scale)
{
    const float8 ep = powp8(clamp(e, 0.0f, 1.0f), 1.0f / 78.84375f);
    const float8 num = max(ep - 0.8359375f, 0.0f);
    return powp8(num / (18.8515625f - 18.6875f * ep), 1.0f / 0.1593017578125f) * inv_pq_scale;
}

#endif
