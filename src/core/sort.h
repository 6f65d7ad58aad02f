/* One stable sort for every solver's per-step lists (contact cells, Lagrangian triplets, BEM triangle bins).
 *
 * DR_DEFINE_STABLE_SORT(name, T, less) defines
 *     static void name(T *a, T *tmp, size_t n)
 * which sorts a[0..n) by `less` (a function or macro taking two const T * and returning whether the first goes
 * strictly before the second) with tmp (n entries, the caller's, kept between calls) as scratch: runs of 16 sorted
 * by insertion, then bottom-up merges that take from the left run on ties. Being stable, its result is unique
 * whatever the algorithm: equal keys keep their input order, so duplicates summed after it are summed in the order
 * they were generated. It allocates nothing (the C library's qsort takes a buffer from the heap on every call, and is
 * not stable) and is typed, so `less` inlines. */
#ifndef DR_CORE_SORT_H
#define DR_CORE_SORT_H

#include <stddef.h>
#include <string.h>

#define DR_DEFINE_STABLE_SORT(name, T, less)                                                                       \
    static void name(T *a, T *tmp, size_t n)                                                                       \
    {                                                                                                              \
        enum { RUN_ = 16 };                                                                                        \
        for (size_t lo_ = 0; lo_ < n; lo_ += RUN_) {                                                               \
            size_t hi_ = lo_ + RUN_ < n ? lo_ + RUN_ : n;                                                          \
            for (size_t k_ = lo_ + 1; k_ < hi_; k_++) {                                                            \
                T t_ = a[k_];                                                                                      \
                size_t m_ = k_;                                                                                    \
                while (m_ > lo_ && less(&t_, &a[m_ - 1])) {                                                        \
                    a[m_] = a[m_ - 1];                                                                             \
                    m_--;                                                                                          \
                }                                                                                                  \
                a[m_] = t_;                                                                                        \
            }                                                                                                      \
        }                                                                                                          \
        T *src_ = a, *dst_ = tmp;                                                                                  \
        for (size_t w_ = RUN_; w_ < n; w_ *= 2) {                                                                  \
            for (size_t lo_ = 0; lo_ < n; lo_ += 2 * w_) {                                                         \
                size_t mid_ = lo_ + w_ < n ? lo_ + w_ : n, hi_ = lo_ + 2 * w_ < n ? lo_ + 2 * w_ : n;              \
                size_t i_ = lo_, j_ = mid_, o_ = lo_;                                                              \
                while (i_ < mid_ && j_ < hi_) dst_[o_++] = less(&src_[j_], &src_[i_]) ? src_[j_++] : src_[i_++];   \
                while (i_ < mid_) dst_[o_++] = src_[i_++];                                                         \
                while (j_ < hi_) dst_[o_++] = src_[j_++];                                                          \
            }                                                                                                      \
            T *t_ = src_;                                                                                          \
            src_ = dst_;                                                                                           \
            dst_ = t_;                                                                                             \
        }                                                                                                          \
        if (src_ != a && n > 0) memcpy(a, src_, n * sizeof *a);                                                    \
    }

#endif
