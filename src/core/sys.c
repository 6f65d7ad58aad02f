/* Timers, the scratch directory, parallel-for over OpenMP and the xoshiro256** rng. */
#include "core.h"

#include <stdio.h>
#include <stdlib.h>
#include <time.h>
#include <unistd.h>
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

/* libgomp spins a waiting thread for 300,000 iterations (~0.3 ms) at every barrier before it sleeps:
   beside a busy process on a shared node the spinning thread holds the core its descheduled partner
   needs to reach the barrier. Sleeping at once (passive) costs a wake-up at each of a substep's ~45
   parallel regions on a quiet machine. A 64k-particle dam break, 2 threads, 12 frames (274 substeps),
   quiet / with one busy process beside it, runs interleaved:
     libgomp's default             7.4–8.1 s / 36–46 s (about 5×)
     OMP_WAIT_POLICY=active        7.2–7.9 s / 18.6 s
     OMP_WAIT_POLICY=passive       9.0–9.3 s / 12.7–13.5 s
     GOMP_SPINCOUNT=3000 (chosen)  7.6–8.3 s / 13.1–14.2 s (1.7×)
     (1000 alike but 8.1–8.6 s quiet; 10,000 15.6–16 s busy; 30,000 20 s busy)
   libgomp reads the variables once, when it is loaded, before main: so the process sets the variable and
   starts itself again. */
void dr_thread_defaults(char **argv)
{
    if (!argv || !argv[0] || getenv("OMP_WAIT_POLICY") || getenv("GOMP_SPINCOUNT")) return;
    if (setenv("GOMP_SPINCOUNT", DR_SPINCOUNT_DEFAULT, 0) != 0) return;
    execv("/proc/self/exe", argv); /* returns only on failure: run on with libgomp's default */
}

void dr_thread_wait_describe(char *buf, size_t size)
{
    const char *w = getenv("OMP_WAIT_POLICY"), *c = getenv("GOMP_SPINCOUNT");
    if (w) snprintf(buf, size, "OMP_WAIT_POLICY=%s", w);
    else if (c) snprintf(buf, size, "GOMP_SPINCOUNT=%s", c);
    else snprintf(buf, size, "OpenMP's default wait");
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
