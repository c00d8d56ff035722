/* firmware_startup.c - the vector table and reset of the Cortex-M7 firmware (QEMU's mps2-an500 board).
 *
 * Written by hand (rollbot_oc/export/c) for `rollbot-oc export-c --target cortex-m7`.  At reset: the FPU on
 * (CP10 and CP11, full access), the initialised data copied from flash to RAM (firmware_mps2_an500.ld
 * places it there), .bss zeroed, newlib's semihosting handles opened, then main(argc, argv) with the
 * command line the debugger (QEMU's -semihosting-config arg=...) gives, and exit with its status.
 * A fault ends the program through semihosting with status 1 instead of hanging the emulator.
 */
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

extern uint32_t __stack_top__, __data_load__, __data_start__, __data_end__, __bss_start__, __bss_end__;
extern void initialise_monitor_handles(void);
extern void __libc_init_array(void);
extern int main(int argc, char** argv);

void Reset_Handler(void);
void Fault_Handler(void);

#define SEMIHOSTING_EXIT 0x18
#define SEMIHOSTING_GET_CMDLINE 0x15
#define ADP_STOPPED_RUNTIME_ERROR 0x20023

static int semihosting(int operation, void* argument) {
    register int r0 __asm("r0") = operation;
    register void* r1 __asm("r1") = argument;
    __asm volatile("bkpt 0xAB" : "+r"(r0) : "r"(r1) : "memory");
    return r0;
}

/* Exceptions 0-15 of the ARMv7-M vector table: the initial stack pointer, reset, then the faults. */
__attribute__((section(".vectors"), used)) void (*const rollbot_vector_table[16])(void) = {
    (void (*)(void))(uintptr_t)&__stack_top__, Reset_Handler, Fault_Handler, Fault_Handler, Fault_Handler,
    Fault_Handler, Fault_Handler, 0, 0, 0, 0, Fault_Handler, Fault_Handler, 0, Fault_Handler, Fault_Handler};

void Fault_Handler(void) {
    semihosting(SEMIHOSTING_EXIT, (void*)ADP_STOPPED_RUNTIME_ERROR);
    for (;;) {
    }
}

static char command_line[256];
static char* arguments[16];

static int split_command_line(void) {
    struct { char* buffer; int length; } block = {command_line, (int)sizeof(command_line) - 1};
    int argc = 0;
    char* p = command_line;
    if (semihosting(SEMIHOSTING_GET_CMDLINE, &block) != 0) return 0;
    command_line[block.length] = 0;
    while (*p && argc < 15) {
        while (*p == ' ') *p++ = 0;
        if (!*p) break;
        arguments[argc++] = p;
        while (*p && *p != ' ') ++p;
    }
    arguments[argc] = 0;
    return argc;
}

void Reset_Handler(void) {
    volatile uint32_t* cpacr = (volatile uint32_t*)0xE000ED88u;
    *cpacr |= 0xFu << 20; /* CP10 and CP11: the FPU, full access */
    __asm volatile("dsb\n\tisb" ::: "memory");
    memcpy(&__data_start__, &__data_load__, (size_t)((char*)&__data_end__ - (char*)&__data_start__));
    memset(&__bss_start__, 0, (size_t)((char*)&__bss_end__ - (char*)&__bss_start__));
    initialise_monitor_handles();
    __libc_init_array();
    {
        int argc = split_command_line();
        exit(main(argc, arguments));
    }
}
