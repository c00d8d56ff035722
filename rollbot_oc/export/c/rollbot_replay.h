/* rollbot_replay.h - the replay of a recorded run through the step: what the board received, and what it gave.
 *
 * Written by hand (rollbot_oc/export/c); used by main.c (make check) and firmware_main.c (make qemu-check).
 *
 * The file (replay_log.bin, written by rollbot-oc export-c from a closed-loop run of the Python NMPC with this
 * step; rollbot_oc/export/replay.py), little-endian: "RBREPLAY", uint32 version (2), periods, the memory's size
 * and the window's size (doubles); then per period, all doubles:
 *   k; the measurement (12: t, position 2, quaternion 4, omega 3, theta, theta_dot);
 *   n, then n pairs (index, value): the host's edits of the memory before measure;
 *   n, then n pairs: its edits after measure;
 *   solving (0 or 1), then, if 1, the reference window (window size) the solve was given;
 *   the commit inputs late, done, fallback_pid, pid_speed;
 *   what the Python NMPC's step gave: accel, speed (NaN unless by speed), by_speed, event, mode.
 */
#ifndef ROLLBOT_REPLAY_H
#define ROLLBOT_REPLAY_H

#include <stdio.h>

#include "rollbot_controller.h"

#define ROLLBOT_REPLAY_MAX_EDITS 64 /* export.replay.MAX_EDITS */

typedef struct {
    long k;
    rollbot_measurement m;
    int edits[2];                                   /* before and after measure */
    double edit[2][ROLLBOT_REPLAY_MAX_EDITS][2];    /* (index, value) */
    int solving;
    double window[ROLLBOT_WINDOW_SIZE];
    rollbot_commit_inputs inputs;
    rollbot_command expected;                       /* the Python step's */
} rollbot_replay_period;

/* Open a replay file: its number of periods, or -1 (a message on stderr) if it is not one of this step. */
long rollbot_replay_open(FILE* f, const char* name);

/* The next period of an open replay file: 0, or -1 (a message on stderr) if it ends or is broken. */
int rollbot_replay_read(FILE* f, rollbot_replay_period* p);

/* Run one period through the step as the host and the board did: edits, measure, edits, solve (at a solve
 * instant), commit.  clock (optional) reads a clock; *total and *solve (optional) get the time of the period's
 * calls and of its solve (0 if none) in its units.  Returns 0, or -1 if an edit or the generated code fails. */
int rollbot_replay_period_run(rollbot_context* ctx, const rollbot_replay_period* p, rollbot_command* command,
                              double (*clock)(void), double* total, double* solve);

/* Whether a command differs from the recorded one beyond `tolerance` (accel, speed) or in by_speed, event or
 * mode; *diff (if not null) becomes the larger of itself and the command's difference. */
int rollbot_replay_differs(const rollbot_command* got, const rollbot_command* expected, double tolerance,
                           double* diff);

#endif
