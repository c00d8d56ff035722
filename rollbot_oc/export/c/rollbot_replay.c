/* rollbot_replay.c - reading a recorded run and running it through the step (rollbot_replay.h). */
#include <math.h>
#include <stdint.h>
#include <string.h>

#include "rollbot_replay.h"

long rollbot_replay_open(FILE* f, const char* name) {
    char magic[8];
    uint32_t header[4];
    if (fread(magic, 1, 8, f) != 8 || memcmp(magic, "RBREPLAY", 8) != 0 || fread(header, 4, 4, f) != 4 ||
        header[0] != 2) {
        fprintf(stderr, "replay: %s: not a replay file of the exported step (version 2)\n", name);
        return -1;
    }
    if (header[2] != ROLLBOT_MEM_SIZE || header[3] != ROLLBOT_WINDOW_SIZE) {
        fprintf(stderr, "replay: %s: recorded for a memory of %lu and windows of %lu doubles, this step's are %d "
                "and %d\n", name, (unsigned long)header[2], (unsigned long)header[3], ROLLBOT_MEM_SIZE,
                ROLLBOT_WINDOW_SIZE);
        return -1;
    }
    return (long)header[1];
}

static int get(FILE* f, double* v, size_t n) { return fread(v, sizeof(double), n, f) == n; }

int rollbot_replay_read(FILE* f, rollbot_replay_period* p) {
    double v[12], n;
    int i;
    if (!get(f, v, 1)) goto broken;
    p->k = (long)v[0];
    if (!get(f, (double*)&p->m, 12)) goto broken;
    for (i = 0; i < 2; ++i) {
        if (!get(f, &n, 1) || !(n >= 0 && n <= ROLLBOT_REPLAY_MAX_EDITS)) goto broken;
        p->edits[i] = (int)n;
        if (!get(f, &p->edit[i][0][0], 2 * (size_t)p->edits[i])) goto broken;
    }
    if (!get(f, v, 1)) goto broken;
    p->solving = v[0] != 0.0;
    if (p->solving && !get(f, p->window, ROLLBOT_WINDOW_SIZE)) goto broken;
    if (!get(f, v, 9)) goto broken;
    p->inputs.late = v[0];
    p->inputs.done = v[1];
    p->inputs.fallback_pid = v[2];
    p->inputs.pid_speed = v[3];
    p->expected.accel = v[4];
    p->expected.speed = v[5];
    p->expected.by_speed = v[6] != 0.0;
    p->expected.event = (int)v[7];
    p->expected.mode = (int)v[8];
    return 0;
broken:
    fprintf(stderr, "replay: the replay file ends or is broken in a period\n");
    return -1;
}

static int edit(rollbot_context* ctx, const rollbot_replay_period* p, int which) {
    int i;
    for (i = 0; i < p->edits[which]; ++i)
        if (rollbot_set_memory(ctx, (long)p->edit[which][i][0], p->edit[which][i][1])) return -1;
    return 0;
}

int rollbot_replay_period_run(rollbot_context* ctx, const rollbot_replay_period* p, rollbot_command* command,
                              double (*clock)(void), double* total, double* solve) {
    double t0 = 0.0, t1 = 0.0, t2 = 0.0, elapsed = 0.0;
    if (edit(ctx, p, 0)) return -1;
    if (clock) t0 = clock();
    if (rollbot_period_measure(ctx, p->k, &p->m)) return -1;
    if (clock) elapsed += clock() - t0;
    if (edit(ctx, p, 1)) return -1;
    if (clock) t1 = clock();
    if (p->solving && rollbot_period_solve(ctx, p->window, 0)) return -1;
    if (clock) t2 = clock();
    if (rollbot_period_commit(ctx, &p->inputs, command)) return -1;
    if (clock) elapsed += clock() - t1;
    if (total) *total = elapsed;
    if (solve) *solve = p->solving ? t2 - t1 : 0.0;
    return 0;
}

int rollbot_replay_differs(const rollbot_command* got, const rollbot_command* expected, double tolerance,
                           double* diff) {
    double d = fabs(got->accel - expected->accel);
    double s = isnan(got->speed) && isnan(expected->speed) ? 0.0 : fabs(got->speed - expected->speed);
    if (d != d || s != s) d = INFINITY;
    if (s > d) d = s;
    if (diff && !(d <= *diff)) *diff = d;
    return !(d <= tolerance) || got->by_speed != expected->by_speed || got->event != expected->event ||
           got->mode != expected->mode;
}
