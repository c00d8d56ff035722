/* main.c - replay a recorded log through the controller and compare with the Python controller's commands.
 *
 * Usage: replay LOG [TOLERANCE]
 * LOG: one line per control period: the measurement (t, position 2, quaternion 4, omega 3, theta,
 * theta_dot), the command the Python embedded controller gave (rad/s^2) and its status.
 * Prints the largest difference of the commands and the step's time (median, p95, max, over all periods
 * and over the solve instants); exits 1 if the difference exceeds TOLERANCE (default 1e-9) or a status
 * differs, 2 if the log cannot be read.  A host program: it reads a file and keeps its timings on the
 * heap; the step itself (rollbot_step) uses only the static context.
 */
#define _POSIX_C_SOURCE 199309L
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <time.h>

#include "rollbot_controller.h"

static rollbot_context ctx;  /* static: no heap in the step */

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
    double row[14], diff = 0.0, *all = 0, *solves = 0;
    long steps = 0, n_solves = 0, capacity = 0, mismatched = 0;
    double tolerance = argc > 2 ? atof(argv[2]) : 1e-9;
    rollbot_measurement m;
    rollbot_command command;
    if (argc < 2 || (log = fopen(argv[1], "r")) == 0) {
        fprintf(stderr, "replay: cannot read the log %s\n", argc < 2 ? "(none given)" : argv[1]);
        return 2;
    }
    rollbot_init(&ctx);
    for (;;) {
        int i, got = 0;
        struct timespec start, stop;
        double seconds;
        for (i = 0; i < 14; ++i) got += fscanf(log, "%lf", &row[i]) == 1;
        if (got == 0) break;
        if (got != 14) {
            fprintf(stderr, "replay: %s: line %ld has %d numbers, not 14\n", argv[1], steps + 1, got);
            return 2;
        }
        m.t = row[0];
        m.position[0] = row[1]; m.position[1] = row[2];
        for (i = 0; i < 4; ++i) m.quaternion[i] = row[3 + i];
        for (i = 0; i < 3; ++i) m.omega[i] = row[7 + i];
        m.theta = row[10];
        m.theta_dot = row[11];
        clock_gettime(CLOCK_MONOTONIC, &start);
        if (rollbot_step(&ctx, &m, &command)) {
            fprintf(stderr, "replay: rollbot_step failed at period %ld\n", steps);
            return 1;
        }
        clock_gettime(CLOCK_MONOTONIC, &stop);
        seconds = (double)(stop.tv_sec - start.tv_sec) + 1e-9 * (double)(stop.tv_nsec - start.tv_nsec);
        if (steps >= capacity) {
            capacity = capacity ? 2 * capacity : 4096;
            all = realloc(all, (size_t)capacity * sizeof(double));
            solves = realloc(solves, (size_t)capacity * sizeof(double));
            if (all == 0 || solves == 0) return 2;
        }
        all[steps] = seconds;
        if (command.status == ROLLBOT_STATUS_SOLVED || command.status == ROLLBOT_STATUS_QP_FAILED)
            solves[n_solves++] = seconds;
        if (fabs(command.accel - row[12]) > diff || command.accel != command.accel) diff = fabs(command.accel - row[12]);
        mismatched += command.status != (int)row[13];
        ++steps;
    }
    fclose(log);
    printf("replayed %ld periods, %ld solve instants\n", steps, n_solves);
    printf("max |diff| = %.3e (commands, rad/s^2), %ld statuses differ\n", diff, mismatched);
    summary("all periods", all, steps);
    summary("solve instants", solves, n_solves);
    printf("context: %lu bytes (work arrays %lu bytes)\n", rollbot_context_bytes(),
           (unsigned long)(sizeof(ctx.arg) + sizeof(ctx.res) + sizeof(ctx.iw) + sizeof(ctx.w)));
    free(all);
    free(solves);
    if (steps == 0 || !(diff <= tolerance) || mismatched) {
        printf("check FAILED: tolerance %.1e\n", tolerance);
        return 1;
    }
    printf("check passed: tolerance %.1e\n", tolerance);
    return 0;
}
