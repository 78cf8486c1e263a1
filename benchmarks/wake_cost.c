/* CPU time one sleep/wake-up costs on this machine, without Python:
 *   cc -O2 benchmarks/wake_cost.c -o /tmp/wake_cost && /tmp/wake_cost
 * (python -m benchmarks.wake_cost measures the same from Python.) */
#include <stdio.h>
#include <sys/resource.h>
#include <time.h>

static double cpu_s(void) {
    struct rusage usage;
    getrusage(RUSAGE_SELF, &usage);
    return usage.ru_utime.tv_sec + usage.ru_stime.tv_sec + 1e-6 * (usage.ru_utime.tv_usec + usage.ru_stime.tv_usec);
}

int main(void) {
    const int wakes = 2000;
    struct timespec two_ms = {0, 2000000};
    double before = cpu_s();
    for (int i = 0; i < wakes; i++) nanosleep(&two_ms, NULL);
    printf("C nanosleep: %.1f us of CPU per wake-up\n", (cpu_s() - before) / wakes * 1e6);
    return 0;
}
