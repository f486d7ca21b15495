# firmware/runtime/firmware.mk: the builds of a firmware on the hilbench runtime, for its Makefile to
# include (firmware/template/Makefile is the example). The including Makefile sets
#   NAME     the build's name (its files are build/$(NAME)_sil, build/$(NAME)_avr.elf, ...)
#   SRC      the firmware's C sources (the folder also holds its hrt_config.h)
#   RUNTIME  this folder (e.g. ../runtime)
# and may set DEFS (extra -D flags for every build) and HBP_DEFS (the protocol capacities; default
# -DHBP_MAX_EDGES=16u, the protocol's). Goals:
#   sil      a host executable (software in the loop): `hilbench run sil:build/$(NAME)_sil`, or
#            `hilbench run sil:.` on the folder (the bench runs `make sil` and finds it)
#   avr      an ATmega328P ELF at 16 MHz, USART0 at 250 kbaud: `hilbench run simavr:build/$(NAME)_avr.elf`
#   m4       a Cortex-M4 ELF (Arm MPS2 AN386, QEMU): `hilbench run qemu:build/$(NAME)_m4.elf`
#   check    the sources with the strict flags for a 16-bit int (avr-gcc, no link)
# Every build uses the strict flags, -Werror included.
RUNTIME ?= ../runtime
PROTO := $(RUNTIME)/../../firmware_protocol
BUILD ?= build
FW_DIR := $(CURDIR)
STRICT := -std=c99 -pedantic -Wall -Wextra -Wconversion -Werror
HBP_DEFS ?=
INCLUDES := -I$(FW_DIR) -I$(RUNTIME) -I$(PROTO)
CORE := $(RUNTIME)/hrt.c $(RUNTIME)/hrt_link.c $(PROTO)/hbp.c
HEADERS := $(wildcard $(FW_DIR)/*.h) $(wildcard $(RUNTIME)/*.h) $(wildcard $(PROTO)/*.h)

all: sil

sil: $(BUILD)/$(NAME)_sil
$(BUILD)/$(NAME)_sil: $(SRC) $(CORE) $(RUNTIME)/ports/host/hrt_host.c $(HEADERS)
	@mkdir -p $(BUILD)
	$(CC) $(STRICT) -O2 $(HBP_DEFS) $(DEFS) $(INCLUDES) $(SRC) $(CORE) $(RUNTIME)/ports/host/hrt_host.c -o $@

AVR_CC ?= avr-gcc
AVR_MCU ?= atmega328p
avr: $(BUILD)/$(NAME)_avr.elf
$(BUILD)/$(NAME)_avr.elf: $(SRC) $(CORE) $(RUNTIME)/ports/avr/hrt_avr.c $(HEADERS)
	@mkdir -p $(BUILD)
	$(AVR_CC) $(STRICT) -mmcu=$(AVR_MCU) -DF_CPU=16000000UL -Os -ffunction-sections -fdata-sections \
	    -Wl,--gc-sections $(HBP_DEFS) $(DEFS) $(INCLUDES) $(SRC) $(CORE) $(RUNTIME)/ports/avr/hrt_avr.c -o $@

check:
	for s in $(SRC) $(CORE); do $(AVR_CC) $(STRICT) -mmcu=$(AVR_MCU) -Os $(HBP_DEFS) $(DEFS) $(INCLUDES) -c $$s -o /dev/null || exit 1; done

m4: $(BUILD)/$(NAME)_m4.elf
$(BUILD)/$(NAME)_m4.elf: $(SRC) $(CORE) $(HEADERS)
	@mkdir -p $(BUILD)
	$(MAKE) -C $(RUNTIME)/ports/cortex_m4 app NAME=$(NAME) APP_DIR=$(FW_DIR) OUT=$(abspath $(BUILD)) \
	    APP_SRC="$(abspath $(SRC))" DEFS="$(HBP_DEFS) $(DEFS)"

clean:
	rm -rf $(BUILD)

.PHONY: all sil avr m4 check clean
