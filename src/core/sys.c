/* Timers, the scratch directory, parallel-for over OpenMP and the xoshiro256** rng. */
#include "core.h"

#include <stdlib.h>
#include <time.h>
#ifdef _OPENMP
#include <omp.h>
#endif

double dr_time_now(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double)ts.tv_sec + 1e-9 * (double)ts.tv_nsec;
}

const char *dr_temp_dir(void)
{
    const char *t = getenv("TMPDIR");
    return t && t[0] ? t : "/tmp";
}

void dr_set_threads(int n)
{
#ifdef _OPENMP
    if (n > 0) omp_set_num_threads(n);
#else
    (void)n;
#endif
}

int dr_threads(void)
{
#ifdef _OPENMP
    return omp_get_max_threads();
#else
    return 1;
#endif
}

void dr_parallel_for(long count, long grain, DrRangeFn fn, void *ctx)
{
    if (count <= 0) return;
    if (grain < 1) grain = 1;
    long nthreads = dr_threads();
    long chunks = count / grain;
    if (chunks < 1) chunks = 1;
    if (chunks > nthreads) chunks = nthreads;
    if (chunks == 1) {
        fn(0, count, ctx);
        return;
    }
#pragma omp parallel for schedule(static, 1) num_threads((int)chunks)
    for (long c = 0; c < chunks; c++) {
        long b = count * c / chunks, e = count * (c + 1) / chunks;
        if (e > b) fn(b, e, ctx);
    }
}

static uint64_t splitmix64(uint64_t *x)
{
    uint64_t z = (*x += 0x9e3779b97f4a7c15ULL);
    z = (z ^ (z >> 30)) * 0xbf58476d1ce4e5b9ULL;
    z = (z ^ (z >> 27)) * 0x94d049bb133111ebULL;
    return z ^ (z >> 31);
}

void dr_rng_seed(DrRng *rng, uint64_t seed)
{
    for (int i = 0; i < 4; i++) rng->s[i] = splitmix64(&seed);
}

static inline uint64_t rotl(uint64_t x, int k) { return (x << k) | (x >> (64 - k)); }

uint64_t dr_rng_next(DrRng *rng)
{
    uint64_t *s = rng->s;
    uint64_t result = rotl(s[1] * 5, 7) * 9;
    uint64_t t = s[1] << 17;
    s[2] ^= s[0];
    s[3] ^= s[1];
    s[1] ^= s[2];
    s[0] ^= s[3];
    s[2] ^= t;
    s[3] = rotl(s[3], 45);
    return result;
}

double dr_rng_uniform(DrRng *rng) { return (double)(dr_rng_next(rng) >> 11) * 0x1.0p-53; }
