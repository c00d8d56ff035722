# The controller on a Cortex-M7 (written by `rollbot-oc export-c --target cortex-m7`; included by Makefile).
#   make firmware     app.elf for QEMU's mps2-an500 board (Cortex-M7, FPv5 double-precision FPU), and app.map
#   make qemu-check   replays the first PERIODS periods of the recorded run (replay_log.bin) on it and on the host
#                     (firmware_host: the same program and step built for this machine) and compares
#                     (firmware_check.py): max |diff|, instructions per solve, RAM and flash.  PERIODS=0: all.
# Needs arm-none-eabi-gcc with newlib (Debian: gcc-arm-none-eabi, libnewlib-arm-none-eabi), qemu-system-arm
# (qemu-system-arm) and python3.
ARM_CC ?= arm-none-eabi-gcc
ARM_NM ?= arm-none-eabi-nm
QEMU ?= qemu-system-arm
PYTHON ?= python3
PERIODS ?= 170
QEMU_TIMEOUT ?= 1800
ARM_ARCH = -mcpu=cortex-m7 -mfpu=fpv5-d16 -mfloat-abi=hard -mthumb
ARM_CFLAGS ?= -std=c99 -O2 -Wall -Werror -ffunction-sections -fdata-sections
STEP_OBJECTS = arm/rollbot_step.o arm/rollbot_controller.o arm/rollbot_data.o
ARM_OBJECTS = $(STEP_OBJECTS) arm/rollbot_replay.o arm/firmware_main.o arm/firmware_startup.o
QEMU_ARGS = -machine mps2-an500 -nographic -monitor none -serial none -icount shift=0 -kernel app.elf \
	-semihosting-config enable=on,target=native,arg=app.elf,arg=replay_log.bin,arg=firmware_commands.bin,$\
	arg=$(PERIODS)

.PHONY: firmware qemu-check clean-firmware

firmware: app.elf

arm/%.o: %.c $(HEADERS)
	@mkdir -p arm
	$(ARM_CC) $(ARM_ARCH) $(ARM_CFLAGS) $(FP) -c $< -o $@

# the step with the flags the NMPC compiles it with (step.mk's STEP_FLAGS), as on the host
arm/rollbot_step.o: rollbot_step.c rollbot_step.h
	@mkdir -p arm
	$(ARM_CC) $(ARM_ARCH) $(ARM_CFLAGS) $(STEP_FLAGS) -c $< -o $@

app.elf: $(ARM_OBJECTS) firmware_mps2_an500.ld
	$(ARM_CC) $(ARM_ARCH) --specs=rdimon.specs -T firmware_mps2_an500.ld -Wl,--gc-sections \
		-Wl,-Map=app.map -o $@ $(ARM_OBJECTS) -lm

# the host build of the same program links the step's library (the NMPC's own build of the same source)
firmware_host: firmware_main.o rollbot_replay.o $(OBJECTS) librollbot_step.so
	$(CC) $(CFLAGS) $(FP) -o $@ firmware_main.o rollbot_replay.o $(OBJECTS) $(STEP_LIB) -lm

qemu-check: app.elf firmware_host
	./firmware_host replay_log.bin host_commands.bin $(PERIODS)
	timeout $(QEMU_TIMEOUT) $(QEMU) $(QEMU_ARGS)
	$(PYTHON) firmware_check.py --map app.map --nm $(ARM_NM) replay_log.bin firmware_commands.bin \
		host_commands.bin $(STEP_OBJECTS)

clean: clean-firmware

clean-firmware:
	rm -rf arm app.elf app.map firmware_host firmware_commands.bin host_commands.bin
