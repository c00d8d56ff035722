/* rollbot_controller.c - the API of rollbot_controller.h around the generated step (no heap). */
#include <string.h>

#include "rollbot_controller.h"

typedef char rollbot_measurement_is_12_doubles[sizeof(rollbot_measurement) == 12 * sizeof(double) ? 1 : -1];

unsigned long rollbot_context_bytes(void) { return (unsigned long)sizeof(rollbot_context); }

int rollbot_init(rollbot_context* ctx) {
    memcpy(ctx->mem, rollbot_initial_memory, sizeof(ctx->mem));
    ctx->solved = 0;
    return 0;
}

int rollbot_set_memory(rollbot_context* ctx, long index, double value) {
    if (index < 0 || index >= ROLLBOT_MEM_SIZE) return -1;
    ctx->mem[index] = value;
    return 0;
}

/* rollbot_measure(mem, meas, k) -> (z, mem_next) */
int rollbot_period_measure(rollbot_context* ctx, long k, const rollbot_measurement* m) {
    memcpy(ctx->meas, m, sizeof(ctx->meas));
    ctx->k = (double)k;
    ctx->solved = 0;
    ctx->arg[0] = ctx->mem;
    ctx->arg[1] = ctx->meas;
    ctx->arg[2] = &ctx->k;
    ctx->res[0] = ctx->z;
    ctx->res[1] = ctx->mem_next;
    if (rollbot_measure(ctx->arg, ctx->res, ctx->iw, ctx->work, 0)) return -1;
    memcpy(ctx->mem, ctx->mem_next, sizeof(ctx->mem));
    return 0;
}

/* rollbot_solve(mem, z, window) -> (w, lam_w, lam_g, ok, retried) */
int rollbot_period_solve(rollbot_context* ctx, const double* window, int* ok) {
    ctx->arg[0] = ctx->mem;
    ctx->arg[1] = ctx->z;
    ctx->arg[2] = window;
    ctx->res[0] = ctx->w;
    ctx->res[1] = ctx->lam_w;
    ctx->res[2] = ctx->lam_g;
    ctx->res[3] = &ctx->ok;
    ctx->res[4] = &ctx->retried;
    if (rollbot_solve(ctx->arg, ctx->res, ctx->iw, ctx->work, 0)) return -1;
    ctx->solved = 1;
    if (ok) *ok = ctx->ok != 0.0;
    return 0;
}

/* rollbot_commit(mem, z, k, w, lam_w, lam_g, ok, late, solving, done, fallback_pid, pid_speed)
 *   -> (accel, speed, by_speed, mem_next, event); without a solve this period, the memory's own solution */
int rollbot_period_commit(rollbot_context* ctx, const rollbot_commit_inputs* in, rollbot_command* command) {
    static const double zero = 0.0, one = 1.0;
    int solved = ctx->solved;
    ctx->arg[0] = ctx->mem;
    ctx->arg[1] = ctx->z;
    ctx->arg[2] = &ctx->k;
    ctx->arg[3] = solved ? ctx->w : ctx->mem + ROLLBOT_MEM_W;
    ctx->arg[4] = solved ? ctx->lam_w : ctx->mem + ROLLBOT_MEM_LAM_W;
    ctx->arg[5] = solved ? ctx->lam_g : ctx->mem + ROLLBOT_MEM_LAM_G;
    ctx->arg[6] = solved ? &ctx->ok : &zero;
    ctx->arg[7] = solved ? &in->late : &zero;
    ctx->arg[8] = solved ? &one : &zero;
    ctx->arg[9] = &in->done;
    ctx->arg[10] = &in->fallback_pid;
    ctx->arg[11] = &in->pid_speed;
    ctx->res[0] = &ctx->out[0];
    ctx->res[1] = &ctx->out[1];
    ctx->res[2] = &ctx->out[2];
    ctx->res[3] = ctx->mem_next;
    ctx->res[4] = &ctx->out[3];
    if (rollbot_commit(ctx->arg, ctx->res, ctx->iw, ctx->work, 0)) return -1;
    memcpy(ctx->mem, ctx->mem_next, sizeof(ctx->mem));
    ctx->solved = 0;
    command->accel = ctx->out[0];
    command->speed = ctx->out[1];
    command->by_speed = ctx->out[2] != 0.0;
    command->event = (int)ctx->out[3];
    command->mode = (int)ctx->mem[ROLLBOT_MEM_MODE];
    return 0;
}
