/* rollbot_controller.c - the API of rollbot_controller.h around the generated step (no heap). */
#include <string.h>

#include "rollbot_controller.h"

typedef char rollbot_measurement_is_12_doubles[sizeof(rollbot_measurement) == 12 * sizeof(double) ? 1 : -1];

unsigned long rollbot_context_bytes(void) { return (unsigned long)sizeof(rollbot_context); }

int rollbot_init(rollbot_context* ctx) {
    memcpy(ctx->mem, rollbot_initial_memory, sizeof(ctx->mem));
    ctx->reference = &rollbot_bundled_reference;
    return 0;
}

int rollbot_set_reference(rollbot_context* ctx, const rollbot_reference* reference) {
    if (reference == 0 || reference->legs < 1 || reference->columns < reference->legs) return -1;
    ctx->reference = reference;
    return 0;
}

/* Leg `leg` from its column `local` on, its last column repeated: states (10, N+1), accelerations (N),
 * the stop (2), the leg's duration and 1 if it is the last leg (EmbeddedReference._leg_window). */
static void leg_window(const rollbot_reference* r, long leg, long local, double* out) {
    long first, end, i, j, node, count;
    if (leg > r->legs - 1) leg = r->legs - 1;
    first = r->starts[leg];
    end = leg + 1 < r->legs ? r->starts[leg + 1] : r->columns;
    count = end - first;
    for (i = 0; i <= ROLLBOT_N; ++i) {
        node = first + (local + i < count - 1 ? local + i : count - 1);
        for (j = 0; j < 10; ++j) *out++ = r->Z[10 * node + j];
    }
    for (i = 0; i < ROLLBOT_N; ++i) {
        node = first + (local + i < count - 1 ? local + i : count - 1);
        *out++ = local + i < count ? r->U[node] : 0.0;
    }
    *out++ = r->stops[2 * leg];
    *out++ = r->stops[2 * leg + 1];
    *out++ = r->durations[leg];
    *out++ = leg == r->legs - 1 ? 1.0 : 0.0;
}

int rollbot_step(rollbot_context* ctx, const rollbot_measurement* m, rollbot_command* command) {
    long k = (long)ctx->mem[ROLLBOT_MEM_K];
    long leg = (long)ctx->mem[ROLLBOT_MEM_SEGMENT];
    long leg_k = (long)ctx->mem[ROLLBOT_MEM_SEGMENT_K];
    leg_window(ctx->reference, leg, (k - leg_k) / ROLLBOT_EVERY, ctx->ref);
    leg_window(ctx->reference, leg + 1, 0, ctx->ref + ROLLBOT_WINDOW_SIZE);
    memcpy(ctx->meas, m, sizeof(ctx->meas));
    ctx->arg[0] = ctx->mem;
    ctx->arg[1] = ctx->meas;
    ctx->arg[2] = ctx->ref;
    ctx->res[0] = &ctx->accel;
    ctx->res[1] = ctx->mem_next;
    ctx->res[2] = &ctx->status;
    if (rollbot_period(ctx->arg, ctx->res, ctx->iw, ctx->w, 0)) return -1;
    memcpy(ctx->mem, ctx->mem_next, sizeof(ctx->mem));
    command->accel = ctx->accel;
    command->status = (int)ctx->status;
    return 0;
}
