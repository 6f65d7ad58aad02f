/* The background writer: one thread that commits deferred HDF5 handles in submission order, so a
 * stage records a file and carries on computing while the file is compressed and written. */
#include "io/io.h"

#include <hdf5.h>
#include <pthread.h>
#include <signal.h>
#include <stdlib.h>
#include <string.h>

struct DrH5Writer {
    pthread_mutex_t mu;
    pthread_cond_t changed; /* a file was queued or finished, or the thread is asked to stop */
    pthread_t thread;
    bool threaded;          /* false: HDF5 is not thread-safe, submit commits on the caller's thread */
    int max_pending;
    DrH5 **queue;           /* ring of max_pending slots: files waiting, oldest at head */
    int head, queued;
    bool busy;              /* the thread is writing a file taken off the queue */
    bool stop;
    bool failed;            /* the first failure, kept for every later submit and flush */
    DrError failure;
    DrH5WriterStats stats;
};

/* Writes h, or drops it when an earlier file failed: a file after a failed one is never renamed
 * into place. Called without the lock. */
static DrStatus write_one(DrH5 *h, bool drop, DrError *err, double *seconds)
{
    double t0 = dr_time_now();
    DrStatus s = DR_OK;
    if (drop) dr_h5_close(&h); /* a deferred handle: frees its recording, no file exists */
    else s = dr_h5_commit(&h, err);
    *seconds = dr_time_now() - t0;
    return s;
}

/* Records the outcome of one file; called with the lock held. */
static void finish_one(DrH5Writer *w, DrStatus s, const DrError *err, double seconds)
{
    w->stats.files++;
    w->stats.seconds += seconds;
    if (s < 0 && !w->failed) {
        w->failed = true;
        w->failure = *err;
    }
}

static void *writer_main(void *arg)
{
    DrH5Writer *w = arg;
    pthread_mutex_lock(&w->mu);
    for (;;) {
        while (w->queued == 0 && !w->stop) pthread_cond_wait(&w->changed, &w->mu);
        if (w->queued == 0) break; /* stop asked and nothing left */
        DrH5 *h = w->queue[w->head];
        w->queue[w->head] = NULL;
        w->head = (w->head + 1) % w->max_pending;
        w->queued--;
        w->busy = true;
        bool drop = w->failed;
        pthread_mutex_unlock(&w->mu);
        DrError err;
        dr_error_clear(&err);
        double seconds;
        DrStatus s = write_one(h, drop, &err, &seconds);
        pthread_mutex_lock(&w->mu);
        w->busy = false;
        finish_one(w, s, &err, seconds);
        pthread_cond_broadcast(&w->changed);
    }
    pthread_mutex_unlock(&w->mu);
    return NULL;
}

DrStatus dr_h5_writer_create(int max_pending, DrH5Writer **out, DrError *err)
{
    assert(max_pending >= 1);
    *out = NULL;
    DrH5Writer *w;
    DR_TRY(dr_calloc(1, sizeof *w, &w, err));
    DrStatus s = dr_calloc((size_t)max_pending, sizeof *w->queue, &w->queue, err);
    if (s < 0) {
        free(w);
        return s;
    }
    w->max_pending = max_pending;
    pthread_mutex_init(&w->mu, NULL);
    pthread_cond_init(&w->changed, NULL);
    hbool_t safe = 0;
    w->threaded = H5is_library_threadsafe(&safe) >= 0 && safe;
    if (w->threaded) {
        /* The thread starts with every signal blocked (it inherits this mask), so a stop request
         * (SIGTERM, SIGUSR1) reaches a thread of the caller's and never interrupts a write. */
        sigset_t all, old;
        sigfillset(&all);
        pthread_sigmask(SIG_BLOCK, &all, &old);
        int rc = pthread_create(&w->thread, NULL, writer_main, w);
        pthread_sigmask(SIG_SETMASK, &old, NULL);
        if (rc != 0) {
            pthread_cond_destroy(&w->changed);
            pthread_mutex_destroy(&w->mu);
            free(w->queue);
            free(w);
            return dr_error_set(err, DR_ERR_RUNTIME, NULL, 0, 0, "cannot start the file writer thread: %s",
                                strerror(rc));
        }
    }
    *out = w;
    return DR_OK;
}

DrStatus dr_h5_writer_submit(DrH5Writer *w, DrH5 **hp, DrError *err)
{
    DrH5 *h = *hp;
    *hp = NULL;
    assert(h && dr_h5_deferred(h));
    if (!w->threaded) {
        double seconds;
        DrError e;
        dr_error_clear(&e);
        DrStatus s = write_one(h, w->failed, &e, &seconds);
        finish_one(w, s, &e, seconds);
        if (w->failed && err) *err = w->failure;
        return w->failed ? w->failure.status : DR_OK;
    }
    pthread_mutex_lock(&w->mu);
    while (!w->failed && w->queued + (w->busy ? 1 : 0) >= w->max_pending) pthread_cond_wait(&w->changed, &w->mu);
    DrStatus s = DR_OK;
    if (w->failed) {
        s = w->failure.status;
        if (err) *err = w->failure;
    } else {
        w->queue[(w->head + w->queued) % w->max_pending] = h;
        w->queued++;
        h = NULL;
        pthread_cond_broadcast(&w->changed);
    }
    pthread_mutex_unlock(&w->mu);
    dr_h5_close(&h); /* dropped after a failure; NULL when queued */
    return s;
}

DrStatus dr_h5_writer_flush(DrH5Writer *w, DrError *err)
{
    pthread_mutex_lock(&w->mu);
    while (w->queued > 0 || w->busy) pthread_cond_wait(&w->changed, &w->mu);
    DrStatus s = DR_OK;
    if (w->failed) {
        s = w->failure.status;
        if (err) *err = w->failure;
    }
    pthread_mutex_unlock(&w->mu);
    return s;
}

void dr_h5_writer_stats(DrH5Writer *w, DrH5WriterStats *out)
{
    pthread_mutex_lock(&w->mu);
    *out = w->stats;
    pthread_mutex_unlock(&w->mu);
}

void dr_h5_writer_destroy(DrH5Writer **wp)
{
    if (!wp || !*wp) return;
    DrH5Writer *w = *wp;
    *wp = NULL;
    if (w->threaded) {
        pthread_mutex_lock(&w->mu);
        w->stop = true; /* the thread empties the queue before it leaves */
        pthread_cond_broadcast(&w->changed);
        pthread_mutex_unlock(&w->mu);
        pthread_join(w->thread, NULL);
    }
    pthread_cond_destroy(&w->changed);
    pthread_mutex_destroy(&w->mu);
    free(w->queue);
    free(w);
}
