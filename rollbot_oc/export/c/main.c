/* main.c - replay a recorded run through the step and compare with the Python NMPC's step (make check).
 *
 * Usage: replay LOG [TOLERANCE]
 * LOG: replay_log.bin (format in rollbot_replay.h): per control period what the board received from the host
 * (the measurement, the host's edits of the memory, the reference window at a solve instant, the inputs of
 * commit) and what the Python NMPC's step gave.  Runs each period through the step as the board would
 * (rollbot_replay_period_run) and prints the largest difference of the commands and the step's time (median,
 * p95, max over all periods and over the solve instants); exits 1 if a command differs by more than TOLERANCE
 * (default 1e-9, rad/s^2 or rad/s) or an event or mode differs, 2 if the log cannot be read.  A host program:
 * it keeps its timings on the heap; the step itself uses only the static context.
 */
#define _POSIX_C_SOURCE 199309L
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <time.h>

#include "rollbot_replay.h"

static rollbot_context ctx;  /* static: no heap in the step */
static rollbot_replay_period period;

static double seconds(void) {
    struct timespec now;
    clock_gettime(CLOCK_MONOTONIC, &now);
    return (double)now.tv_sec + 1e-9 * (double)now.tv_nsec;
}

static int compare(const void* a, const void* b) {
    double x = *(const double*)a, y = *(const double*)b;
    return (x > y) - (x < y);
}

static void summary(const char* what, double* t, long n) {
    double sum = 0.0;
    long i;
    if (n == 0) return;
    for (i = 0; i < n; ++i) sum += t[i];
    qsort(t, (size_t)n, sizeof(double), compare);
    printf("step time %s (%ld): median %.1f us, p95 %.1f us, max %.1f us, mean %.1f us\n", what, n, 1e6 * t[n / 2],
           1e6 * t[(long)(0.95 * (n - 1))], 1e6 * t[n - 1], 1e6 * sum / (double)n);
}

int main(int argc, char** argv) {
    FILE* log;
    double diff = 0.0, *all, *solves, total, solve;
    long periods, i, n_solves = 0, mismatched = 0;
    double tolerance = argc > 2 ? atof(argv[2]) : 1e-9;
    rollbot_command command;
    if (argc < 2 || (log = fopen(argv[1], "rb")) == 0) {
        fprintf(stderr, "replay: cannot read the log %s\n", argc < 2 ? "(none given)" : argv[1]);
        return 2;
    }
    if ((periods = rollbot_replay_open(log, argv[1])) < 0) return 2;
    all = malloc((size_t)(periods + 1) * sizeof(double));
    solves = malloc((size_t)(periods + 1) * sizeof(double));
    if (all == 0 || solves == 0) return 2;
    rollbot_init(&ctx);
    for (i = 0; i < periods; ++i) {
        if (rollbot_replay_read(log, &period)) return 2;
        if (rollbot_replay_period_run(&ctx, &period, &command, seconds, &total, &solve)) {
            fprintf(stderr, "replay: the step failed at period %ld\n", i);
            return 1;
        }
        all[i] = total;
        if (period.solving) solves[n_solves++] = solve;
        mismatched += rollbot_replay_differs(&command, &period.expected, INFINITY, &diff);
    }
    fclose(log);
    printf("replayed %ld periods, %ld solve instants\n", periods, n_solves);
    printf("max |diff| = %.3e (commands, rad/s^2), %ld events or modes differ\n", diff, mismatched);
    summary("all periods", all, periods);
    summary("solves", solves, n_solves);
    printf("context: %lu bytes (work arrays %lu bytes)\n", rollbot_context_bytes(),
           (unsigned long)(sizeof(ctx.arg) + sizeof(ctx.res) + sizeof(ctx.iw) + sizeof(ctx.work)));
    free(all);
    free(solves);
    if (periods == 0 || !(diff <= tolerance) || mismatched) {
        printf("check FAILED: tolerance %.1e\n", tolerance);
        return 1;
    }
    printf("check passed: tolerance %.1e\n", tolerance);
    return 0;
}
