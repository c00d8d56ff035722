/* firmware_main.c - the step's replay on the robot's processor: the recorded run in, commands out.
 *
 * Usage: firmware REPLAY OUT [PERIODS]
 * Written by hand (rollbot_oc/export/c) for `rollbot-oc export-c --target cortex-m7`; built twice from this one
 * source: for the Cortex-M7 (app.elf, run by QEMU, files through semihosting) and for the host
 * (firmware_host), so that `make qemu-check` compares the two builds of the same program.
 *
 * REPLAY: replay_log.bin (format in rollbot_replay.h): per period what the board received from the host (the
 * measurement, the host's edits of the step's memory, the reference window at a solve instant, the inputs of
 * commit) and what the Python NMPC's step gave.  Each period runs through the step as on the board
 * (rollbot_replay_period_run: edits, rollbot_period_measure, rollbot_period_solve at a solve instant,
 * rollbot_period_commit).
 *
 * OUT (little-endian): "RBFWOUT2", then uint32 version (2), periods, context bytes, the deepest stack a period's
 * calls reached, in bytes (from the caller's stack pointer; painted before each period; 0 on the host), double
 * instructions per SysTick tick (0 on the host); then per period (48 bytes): double accel (rad/s^2), double speed
 * (rad/s, NaN unless by speed), int32 by_speed, int32 event, int32 mode, uint32 solving, uint64 instructions of
 * the period's calls of the step, uint64 instructions of its solve (0 on the host).
 *
 * Instructions: QEMU's Cortex-M has no cycle counter; with -icount shift=0 its virtual clock advances 1 ns per
 * instruction and SysTick, on the processor clock, counts it at a fixed ratio, calibrated at start on a loop of
 * known length.  The step's heap use is none: rollbot_context is static here.
 * PERIODS: replay the first PERIODS periods only (0 or absent: all).  Exit 0, or 2 if a file cannot be read or
 * written, or 1 if the step fails.
 */
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "rollbot_replay.h"

static rollbot_context ctx; /* static: the step uses no heap */
static rollbot_replay_period replay;

#if defined(__arm__)
#define SYST_CSR (*(volatile uint32_t*)0xE000E010u)
#define SYST_RVR (*(volatile uint32_t*)0xE000E014u)
#define SYST_CVR (*(volatile uint32_t*)0xE000E018u)
#define SYST_COUNTFLAG (1u << 16)
#define SYST_MAX 0xFFFFFFu
static uint64_t wraps;

/* SysTick ticks since ticks_start: the 24-bit down-counter extended by its wraps (COUNTFLAG, read at least once
 * per wrap: every 2^24 ticks, far longer than a period's step). */
static uint64_t ticks(void) {
    uint32_t value = SYST_CVR;
    if (SYST_CSR & SYST_COUNTFLAG) {
        ++wraps;
        value = SYST_CVR;
    }
    return (wraps << 24) + (SYST_MAX - value);
}

static void ticks_start(void) {
    SYST_RVR = SYST_MAX;
    SYST_CVR = 0;
    SYST_CSR = 5; /* enabled, processor clock, no interrupt */
    while (SYST_CVR == 0) {
    }
    (void)SYST_CSR; /* reading clears COUNTFLAG */
    wraps = 0;
}

/* Ticks of a loop of 2 instructions (subs, bne) run n times, the reading of the clock included. */
static uint64_t loop_ticks(uint32_t n) {
    uint64_t t0 = ticks();
    __asm volatile("1: subs %0, %0, #1\n\tbne 1b" : "+r"(n)::"cc");
    return ticks() - t0;
}

/* Instructions per tick: the loop run 2^22 and 2^24 times, from the difference of the two (the clock's reading
 * and the call cancel out; one tick of rounding is 2e-6 of it). */
static double calibrate(void) {
    uint64_t shorter = loop_ticks(1u << 22), longer = loop_ticks(1u << 24);
    return longer > shorter ? 2.0 * (double)((1u << 24) - (1u << 22)) / (double)(longer - shorter) : 0.0;
}

extern uint32_t __stack_limit__;
#define STACK_PAINT 0xA5A5A5A5u

static const uint32_t* stack_pointer(void) {
    uint32_t* sp;
    __asm volatile("mov %0, sp" : "=r"(sp));
    return sp;
}

/* Fill the free stack, from its limit to below the caller's frame, with a pattern; stack_used then finds how deep
 * a call from that frame went (the step's stack, without the replay's stdio). */
static void paint_stack(const uint32_t* below) {
    volatile uint32_t* p = &__stack_limit__;
    while ((const uint32_t*)p < below) *p++ = STACK_PAINT;
}

static uint32_t stack_used(const uint32_t* below, const uint32_t* from) {
    const uint32_t* p = &__stack_limit__;
    while (p < below && *p == STACK_PAINT) ++p;
    return (uint32_t)((const char*)from - (const char*)p);
}
#else
static uint64_t ticks(void) { return 0; }
static void ticks_start(void) {}
static double calibrate(void) { return 0.0; }
static uint32_t no_stack[32];
static const uint32_t* stack_pointer(void) { return no_stack + 32; }
static void paint_stack(const uint32_t* below) { (void)below; }
static uint32_t stack_used(const uint32_t* below, const uint32_t* from) {
    (void)below;
    (void)from;
    return 0;
}
#endif

static double clock_ticks(void) { return (double)ticks(); }

typedef struct { /* one period of OUT: 48 bytes, no padding */
    double accel;
    double speed;
    int32_t by_speed;
    int32_t event;
    int32_t mode;
    uint32_t solving;
    uint64_t step_instructions;
    uint64_t solve_instructions;
} out_row;

typedef char out_row_is_48_bytes[sizeof(out_row) == 48 ? 1 : -1];

static int write_u32(FILE* f, uint32_t v) { return fwrite(&v, sizeof v, 1, f) == 1; }

int main(int argc, char** argv) {
    FILE *in, *out;
    uint32_t period, periods, stack = 0;
    long recorded;
    double per_tick;
    rollbot_command command;
    out_row o;
    if (argc < 3) {
        fprintf(stderr, "firmware: usage: firmware REPLAY OUT [PERIODS]\n");
        return 2;
    }
    if ((in = fopen(argv[1], "rb")) == 0 || (recorded = rollbot_replay_open(in, argv[1])) < 0) {
        fprintf(stderr, "firmware: cannot read the replay %s\n", argv[1]);
        return 2;
    }
    periods = (uint32_t)recorded;
    if (argc > 3 && atol(argv[3]) > 0 && (uint32_t)atol(argv[3]) < periods) periods = (uint32_t)atol(argv[3]);
    if ((out = fopen(argv[2], "wb")) == 0) {
        fprintf(stderr, "firmware: cannot write %s\n", argv[2]);
        return 2;
    }
    ticks_start();
    per_tick = calibrate();
    fwrite("RBFWOUT2", 1, 8, out);
    write_u32(out, 2);
    write_u32(out, periods);
    write_u32(out, (uint32_t)rollbot_context_bytes());
    write_u32(out, 0); /* the stack peak, written at the end */
    fwrite(&per_tick, sizeof per_tick, 1, out);
    rollbot_init(&ctx);
    for (period = 0; period < periods; ++period) {
        double total, solve;
        if (rollbot_replay_read(in, &replay)) {
            fprintf(stderr, "firmware: %s: ends at period %lu\n", argv[1], (unsigned long)period);
            return 2;
        }
        {
            const uint32_t* sp = stack_pointer();
            uint32_t used;
            paint_stack(sp - 16);
            if (rollbot_replay_period_run(&ctx, &replay, &command, clock_ticks, &total, &solve)) {
                fprintf(stderr, "firmware: the step failed at period %lu\n", (unsigned long)period);
                return 1;
            }
            used = stack_used(sp - 16, sp);
            if (used > stack) stack = used;
        }
        o.step_instructions = (uint64_t)(total * per_tick + 0.5);
        o.solve_instructions = (uint64_t)(solve * per_tick + 0.5);
        o.accel = command.accel;
        o.speed = command.speed;
        o.by_speed = command.by_speed;
        o.event = command.event;
        o.mode = command.mode;
        o.solving = (uint32_t)replay.solving;
        if (fwrite(&o, sizeof o, 1, out) != 1) {
            fprintf(stderr, "firmware: cannot write %s\n", argv[2]);
            return 2;
        }
    }
    fclose(in);
    if (fseek(out, 20, SEEK_SET) != 0 || !write_u32(out, stack) || fclose(out) != 0) {
        fprintf(stderr, "firmware: cannot write %s\n", argv[2]);
        return 2;
    }
    printf("firmware: %lu periods replayed\n", (unsigned long)periods);
    return 0;
}
