# make firmware: the logger sketch (firmware/pdr_logger) for an Arduino UNO (ATmega328P) with Debian's
# packages, without the Arduino IDE.  Included by the top Makefile.
#
# The packaged core (arduino-core-avr 1.8.7) needs a newer compiler than gcc-avr 5.4 for WString.cpp
# (DECIMAL_DIG), which the sketch does not use: only the core files it does use are built, into an
# archive, so the linker takes just the objects it needs, as the IDE's core.a.

FIRMWARE_PACKAGES := gcc-avr avr-libc arduino-core-avr simavr libsimavr-dev gcc
FIRMWARE_BUILD    ?= firmware/build
FIRMWARE_FLASH_MAX := 32256
FIRMWARE_RAM_MAX   := 1536

ARDUINO_AVR  := /usr/share/arduino/hardware/arduino/avr
ARDUINO_CORE := $(ARDUINO_AVR)/cores/arduino
FIRMWARE_SKETCH := firmware/pdr_logger/pdr_logger.ino
FIRMWARE_HEADERS := firmware/pdr_logger/pdr_controller.h
FIRMWARE_CORE_C   := wiring.c wiring_digital.c wiring_analog.c WInterrupts.c hooks.c
FIRMWARE_CORE_CXX := main.cpp HardwareSerial.cpp HardwareSerial0.cpp Print.cpp abi.cpp new.cpp
FIRMWARE_CORE_OBJ := $(addprefix $(FIRMWARE_BUILD)/core/,$(FIRMWARE_CORE_C:.c=.o) $(FIRMWARE_CORE_CXX:.cpp=.o))

AVR_FLAGS := -mmcu=atmega328p -DF_CPU=16000000L -DARDUINO=10807 -DARDUINO_AVR_UNO -DARDUINO_ARCH_AVR \
             -I$(ARDUINO_CORE) -I$(ARDUINO_AVR)/variants/standard -Os -g -ffunction-sections -fdata-sections
AVR_CFLAGS   := $(AVR_FLAGS) -std=gnu11
AVR_CXXFLAGS := $(AVR_FLAGS) -std=gnu++11 -fno-exceptions -fno-threadsafe-statics -fpermissive

.PHONY: firmware firmware-deps

# The packages, installed where this may (as root, as CI runs); otherwise which ones are missing.
firmware-deps:
	@missing=""; for p in $(FIRMWARE_PACKAGES); do \
	  dpkg-query -W -f='$${Status}' $$p 2>/dev/null | grep -q "ok installed" || missing="$$missing $$p"; done; \
	if [ -n "$$missing" ]; then \
	  if [ "$$(id -u)" = 0 ]; then \
	    echo "installing$$missing"; \
	    apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq $$missing; \
	  else \
	    echo "make firmware needs the Debian packages$$missing: run 'make firmware-deps' as root" >&2; exit 1; \
	  fi; \
	fi

firmware: firmware-deps
	@$(MAKE) --no-print-directory $(FIRMWARE_BUILD)/pdr_logger.hex
	@avr-size -A $(FIRMWARE_BUILD)/pdr_logger.elf | awk -v elf=$(FIRMWARE_BUILD)/pdr_logger.elf \
	  -v flash_max=$(FIRMWARE_FLASH_MAX) -v ram_max=$(FIRMWARE_RAM_MAX) \
	  '$$1 == ".text" || $$1 == ".data" { flash += $$2 } $$1 == ".data" || $$1 == ".bss" { ram += $$2 } \
	   END { printf "%s: flash %d of %d bytes, static RAM %d of %d bytes\n", elf, flash, flash_max, ram, ram_max; \
	         if (flash > flash_max || ram > ram_max) { print "the firmware does not fit" > "/dev/stderr"; exit 1 } }'

$(FIRMWARE_BUILD)/core/%.o: $(ARDUINO_CORE)/%.c
	@mkdir -p $(@D)
	avr-gcc -c $(AVR_CFLAGS) $< -o $@

$(FIRMWARE_BUILD)/core/%.o: $(ARDUINO_CORE)/%.cpp
	@mkdir -p $(@D)
	avr-g++ -c $(AVR_CXXFLAGS) $< -o $@

$(FIRMWARE_BUILD)/core.a: $(FIRMWARE_CORE_OBJ)
	rm -f $@
	avr-ar rcs $@ $^

# The .ino as the IDE compiles it: C++ with Arduino.h first (the sketch declares before it uses).
$(FIRMWARE_BUILD)/pdr_logger.o: $(FIRMWARE_SKETCH) $(FIRMWARE_HEADERS)
	@mkdir -p $(@D)
	avr-g++ -c $(AVR_CXXFLAGS) -Wall -Wextra -Werror -x c++ -include Arduino.h $< -o $@

$(FIRMWARE_BUILD)/pdr_logger.elf: $(FIRMWARE_BUILD)/pdr_logger.o $(FIRMWARE_BUILD)/core.a
	avr-gcc -mmcu=atmega328p -Os -Wl,--gc-sections $^ -lm -o $@

$(FIRMWARE_BUILD)/pdr_logger.hex: $(FIRMWARE_BUILD)/pdr_logger.elf
	avr-objcopy -O ihex -R .eeprom $< $@
