/* CPU time one timed wake-up costs on this machine, without Python: the enforcer's floor.
 *
 *   cc -O2 benchmarks/wake_cost.c -o /tmp/wake_cost && /tmp/wake_cost [RATE_HZ [SECONDS [FIFO_PRIORITY [CPU]]]]
 *
 * A loop of clock_nanosleep(CLOCK_MONOTONIC, TIMER_ABSTIME) at RATE_HZ (default 500) for SECONDS
 * (default 4), at SCHED_FIFO FIFO_PRIORITY if given (0: SCHED_OTHER), pinned to CPU if given: what a
 * slot switch costs when it does nothing but wake up on time.  Prints the thread's CPU time
 * (CLOCK_THREAD_CPUTIME_ID, exact) per wake-up in microseconds, and the wake-up latency (from the
 * due time to the wake-up) p50 and p95.  python -m benchmarks.wake_cost measures the same from Python. */
#define _GNU_SOURCE
#include <sched.h>
#include <stdio.h>
#include <stdlib.h>
#include <time.h>

static long long ns(struct timespec t) { return t.tv_sec * 1000000000LL + t.tv_nsec; }

static int by_value(const void *a, const void *b) {
    long long x = *(const long long *)a, y = *(const long long *)b;
    return (x > y) - (x < y);
}

int main(int argc, char **argv) {
    double rate = argc > 1 ? atof(argv[1]) : 500.0;
    double seconds = argc > 2 ? atof(argv[2]) : 4.0;
    int fifo = argc > 3 ? atoi(argv[3]) : 0;
    int cpu = argc > 4 ? atoi(argv[4]) : -1;
    if (rate <= 0 || seconds <= 0) {
        fprintf(stderr, "usage: wake_cost [RATE_HZ [SECONDS [FIFO_PRIORITY [CPU]]]]\n");
        return 2;
    }
    if (cpu >= 0) {
        cpu_set_t set;
        CPU_ZERO(&set);
        CPU_SET(cpu, &set);
        if (sched_setaffinity(0, sizeof set, &set) != 0) perror("sched_setaffinity");
    }
    if (fifo > 0) {
        struct sched_param param = {fifo};
        if (sched_setscheduler(0, SCHED_FIFO, &param) != 0) perror("sched_setscheduler");
    }
    long long period = (long long)(1e9 / rate);
    int wakes = (int)(rate * seconds);
    long long *late = malloc(sizeof *late * (size_t)wakes);
    if (late == NULL) return 1;
    struct timespec due, now, cpu0, cpu1;
    clock_gettime(CLOCK_MONOTONIC, &due);
    clock_gettime(CLOCK_THREAD_CPUTIME_ID, &cpu0);
    for (int i = 0; i < wakes; i++) {
        long long next = ns(due) + period;
        due.tv_sec = next / 1000000000LL;
        due.tv_nsec = next % 1000000000LL;
        clock_nanosleep(CLOCK_MONOTONIC, TIMER_ABSTIME, &due, NULL);
        clock_gettime(CLOCK_MONOTONIC, &now);
        late[i] = ns(now) - next;
    }
    clock_gettime(CLOCK_THREAD_CPUTIME_ID, &cpu1);
    qsort(late, (size_t)wakes, sizeof *late, by_value);
    printf("wake_cost: %.2f us of CPU per wake-up at %.1f Hz; latency p50 %.1f us, p95 %.1f us\n",
           (ns(cpu1) - ns(cpu0)) / 1e3 / wakes, rate, late[wakes / 2] / 1e3, late[wakes * 95 / 100] / 1e3);
    free(late);
    return 0;
}
