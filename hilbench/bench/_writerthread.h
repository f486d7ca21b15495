/* The recording writers' threads (_npzcolumns.c's archive writer, _csvrows.c's row writer), started
 * and scheduled one way: every signal blocked (a signal is the Python thread's to handle, never an
 * EINTR or a handler run on a writer), and a batch thread (its wake-up does not preempt the
 * simulating thread that woke it; on a busy machine it still gets its fair share, on an idle CPU it
 * runs at once). Needs _GNU_SOURCE before the first include, for SCHED_BATCH. */
#ifndef HILBENCH_WRITERTHREAD_H
#define HILBENCH_WRITERTHREAD_H

#include <pthread.h>
#include <sched.h>
#include <signal.h>

/* pthread_create with every signal blocked in the new thread (it inherits the creator's mask, which
 * is restored here): 0 or an errno */
static int start_writer_thread(pthread_t *thread, void *(*run)(void *), void *arg)
{
    sigset_t all, before;
    sigfillset(&all);
    pthread_sigmask(SIG_SETMASK, &all, &before);
    int err = pthread_create(thread, NULL, run, arg);
    pthread_sigmask(SIG_SETMASK, &before, NULL);
    return err;
}

/* The calling thread as a batch thread (where the system has the policy). */
static void become_batch_thread(void)
{
#ifdef SCHED_BATCH
    struct sched_param batch = {0};
    pthread_setschedparam(pthread_self(), SCHED_BATCH, &batch);
#endif
}

#endif
