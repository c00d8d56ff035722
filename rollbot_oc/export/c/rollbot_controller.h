/* rollbot_controller.h - the NMPC's control step on the robot: measure, solve, commit, once per control period.
 *
 * Written by hand (rollbot_oc/export/c) around rollbot_step.c, which `rollbot-oc export-c` generates from the
 * three CasADi Functions of the Python NMPC's own control period (rollbot_oc/control/nmpc/period.py): the same
 * source the Python NMPC compiles and runs, so the board runs the step the README measures.
 *
 * The step keeps everything it remembers in one vector of doubles, the memory (ROLLBOT_MEM_SIZE; its parts'
 * offsets in rollbot_config.h).  Each period, every ROLLBOT_DT seconds, in this order:
 *   1. rollbot_set_memory: the host's edits of the memory, if any (its supervisor restarting the warm start,
 *      stopping the motor, holding it until a plan starts: TrackingStep.restart, cold, stop_motor, hold_until);
 *   2. rollbot_period_measure: the tilt filter's update and the delay compensation of the measurement to the
 *      tick k (the reduced state z, kept in the context);
 *   3. more edits of the host, if any (made after it saw the measurement: a leg left, a new plan taking over);
 *   4. at a solve instant, rollbot_period_solve: one real-time iteration of the tracking NMPC (ROLLBOT_N
 *      intervals of ROLLBOT_H s, its QP by qrqp, once more from the reference if the warm start failed) on the
 *      reference window the host's supervisor sent (ROLLBOT_WINDOW_SIZE doubles: reference states and
 *      accelerations, the weights of every decision variable, the mission's weights and values);
 *   5. rollbot_period_commit: the step's mode and the command: the solution's acceleration, the previous
 *      solution after a failed or late solve (the host says whether it was late), the brake's speed ramp or a
 *      speed the host's PID gives, zero once the host says the mission is done.
 *
 * What it does NOT do: the supervisor (the mission's modes, the minimum-time plans, the reference windows) runs
 * on the host and sends the windows; computing them on board from plans sent once is the robot link's work.
 *
 * Memory: no heap.  Everything the step needs is inside rollbot_context (ROLLBOT_CONTEXT_BYTES, most of it the
 * generated code's work arrays); declare it static or give it from your own memory.
 * Units: SI, radians; the floor frame has z up; quaternions are scalar first, body -> floor.
 */
#ifndef ROLLBOT_CONTROLLER_H
#define ROLLBOT_CONTROLLER_H

#include "rollbot_config.h"
#include "rollbot_step.h"

#ifdef __cplusplus
extern "C" {
#endif

/* What the controller sees each period (12 doubles in this order). */
typedef struct {
    double t;              /* time the measurement was taken, s (a multiple of ROLLBOT_DT) */
    double position[2];    /* shell-centre position, floor frame, m */
    double quaternion[4];  /* shell orientation, body -> floor, scalar first */
    double omega[3];       /* shell angular velocity, floor frame, rad/s */
    double theta;          /* motor angle, rad */
    double theta_dot;      /* driving speed, rad/s */
} rollbot_measurement;

/* What the host decides for commit (rollbot_oc's TrackingStep.act). */
typedef struct {
    double late;           /* 1 if this period's solve came too late to be used */
    double done;           /* 1 once the mission is done: the command is 0 */
    double fallback_pid;   /* 1: the fallback is the host's PID (a speed); 0: the brake's speed ramp */
    double pid_speed;      /* rad/s, the PID's speed while the mode is ROLLBOT_MODE_PID; else NaN */
} rollbot_commit_inputs;

/* What the step commands for the period. */
typedef struct {
    double accel;          /* motor acceleration, rad/s^2, held over the period */
    double speed;          /* motor speed, rad/s, when commanded by speed (by_speed); else NaN */
    int by_speed;          /* 1 if the motor is commanded by speed (a fallback) */
    int event;             /* what the period did: ROLLBOT_EVENT_* */
    int mode;              /* the step's mode after it: ROLLBOT_MODE_* */
} rollbot_command;

enum { /* rollbot_oc.control.nmpc.period.EVENTS */
    ROLLBOT_EVENT_FOLLOWED = 0, ROLLBOT_EVENT_SOLVED = 1, ROLLBOT_EVENT_SHIFTED = 2, ROLLBOT_EVENT_BRAKE = 3,
    ROLLBOT_EVENT_PID = 4, ROLLBOT_EVENT_FALLBACK = 5, ROLLBOT_EVENT_OFF = 6
};
enum { /* rollbot_oc.control.nmpc.modes.StepMode */
    ROLLBOT_MODE_SOLVE = 0, ROLLBOT_MODE_SHIFTED = 1, ROLLBOT_MODE_RAMP = 2, ROLLBOT_MODE_PID = 3, ROLLBOT_MODE_OFF = 4
};

/* Everything the step remembers and works in; no other memory is used. */
typedef struct {
    double mem[ROLLBOT_MEM_SIZE];       /* the step's memory */
    double mem_next[ROLLBOT_MEM_SIZE];
    double meas[12], k, z[10];          /* this period's measurement, tick and delay-compensated state */
    double w[ROLLBOT_NW], lam_w[ROLLBOT_NW], lam_g[ROLLBOT_NG], ok, retried;  /* this period's solve */
    int solved;                         /* rollbot_period_solve was called this period */
    double out[4];                      /* commit's accel, speed, by_speed, event */
    const casadi_real* arg[ROLLBOT_SZ_ARG];
    casadi_real* res[ROLLBOT_SZ_RES];
    casadi_int iw[ROLLBOT_SZ_IW];
    casadi_real work[ROLLBOT_SZ_W];
} rollbot_context;

#define ROLLBOT_CONTEXT_BYTES (sizeof(rollbot_context))

/* Start a run: the initial memory (the robot the controller believes in, the filter's prior, no solution). */
int rollbot_init(rollbot_context* ctx);

/* The host's edit of the memory: entry `index` set to `value`. Returns 0, or -1 if index is out of range. */
int rollbot_set_memory(rollbot_context* ctx, long index, double value);

/* The measurement m of tick k (the period's number since the start): the filter and the delay compensation.
 * Returns 0, or -1 if the generated code fails. */
int rollbot_period_measure(rollbot_context* ctx, long k, const rollbot_measurement* m);

/* One solve on the host's reference window (ROLLBOT_WINDOW_SIZE doubles), after rollbot_period_measure.
 * Returns 0, or -1 if the generated code fails; *ok (if not null) is 1 if the solve succeeded. */
int rollbot_period_solve(rollbot_context* ctx, const double* window, int* ok);

/* The period's command, after rollbot_period_measure (and rollbot_period_solve at a solve instant).
 * Returns 0, or -1 if the generated code fails. */
int rollbot_period_commit(rollbot_context* ctx, const rollbot_commit_inputs* in, rollbot_command* command);

/* Bytes of a rollbot_context (for callers that allocate it themselves, e.g. through ctypes). */
unsigned long rollbot_context_bytes(void);

#ifdef __cplusplus
}
#endif
#endif
