/* The built firmware on a simulated UNO (libsimavr) with its encoder, current sensor and H-bridge wired
 * to a plant the test steps: the control loop closes through the real firmware.
 *
 *   cosim FIRMWARE.elf SECONDS QUANTUM_US UART_OUT
 *
 * Every QUANTUM_US of simulated time it writes the command the firmware is driving (one int8: 0 motor off,
 * +1 q1 (D7 high), -1 q2; on = the PWM output D9/OC1A enabled) to stdout and reads the plant's state
 * back from stdin (int32 encoder count, int32 ACS712 output in mV): the count's edges are put on D2/D3
 * (A, B in Gray code, one edge at a time, 10 us apart; A = B = 1 at count 0), the voltage on A0.
 * What the firmware sends over its UART goes to UART_OUT byte for byte.  The pins are the sketch's
 * (test_closed_loop.py checks its settings against these). */
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include <simavr/avr_adc.h>
#include <simavr/avr_ioport.h>
#include <simavr/avr_uart.h>
#include <simavr/sim_avr.h>
#include <simavr/sim_elf.h>

#define PORTD_ADDR 0x2B
#define TCCR1A_ADDR 0x80
#define DIR_BIT 7       /* D7 */
#define COM1A1_BIT 7    /* D9's PWM output on */

static const uint8_t GRAY[4] = {0, 1, 3, 2};   /* A << 1 | B, one edge apart */
#define GRAY_AT_ZERO 2                          /* count 0 is A = B = 1, the pull-ups' level at power-up */

static void on_uart_byte(struct avr_irq_t *irq, uint32_t value, void *param)
{
    (void)irq;
    fputc((int)(value & 0xff), (FILE *)param);
}

static int run_until(avr_t *avr, avr_cycle_count_t cycle)
{
    while (avr->cycle < cycle) {
        int state = avr_run(avr);
        if (state == cpu_Done || state == cpu_Crashed) return -1;
    }
    return 0;
}

static int full_io(int fd, void *buf, size_t n, int writing)
{
    size_t done = 0;
    while (done < n) {
        ssize_t k = writing ? write(fd, (char *)buf + done, n - done) : read(fd, (char *)buf + done, n - done);
        if (k <= 0) return -1;
        done += (size_t)k;
    }
    return 0;
}

int main(int argc, char **argv)
{
    if (argc != 5) {
        fprintf(stderr, "usage: cosim FIRMWARE.elf SECONDS QUANTUM_US UART_OUT\n");
        return 2;
    }
    elf_firmware_t firmware;
    memset(&firmware, 0, sizeof firmware);
    if (elf_read_firmware(argv[1], &firmware) != 0) {
        fprintf(stderr, "cosim: cannot read %s\n", argv[1]);
        return 2;
    }
    avr_t *avr = avr_make_mcu_by_name("atmega328p");
    avr_init(avr);
    avr->frequency = 16000000;
    avr_load_firmware(avr, &firmware);
    avr->log = 0;
    avr->vcc = avr->avcc = avr->aref = 5000;   /* the UNO's 5 V: analogRead's reference */

    FILE *uart = fopen(argv[4], "wb");
    uint32_t flags = 0;
    avr_ioctl(avr, AVR_IOCTL_UART_GET_FLAGS('0'), &flags);
    flags &= ~AVR_UART_FLAG_STDIO;
    avr_ioctl(avr, AVR_IOCTL_UART_SET_FLAGS('0'), &flags);
    avr_irq_register_notify(avr_io_getirq(avr, AVR_IOCTL_UART_GETIRQ('0'), UART_IRQ_OUTPUT), on_uart_byte, uart);
    avr_irq_t *pin_a = avr_io_getirq(avr, AVR_IOCTL_IOPORT_GETIRQ('D'), 2);
    avr_irq_t *pin_b = avr_io_getirq(avr, AVR_IOCTL_IOPORT_GETIRQ('D'), 3);
    avr_irq_t *adc0 = avr_io_getirq(avr, AVR_IOCTL_ADC_GETIRQ, ADC_IRQ_ADC0);

    const avr_cycle_count_t end = (avr_cycle_count_t)(atof(argv[2]) * avr->frequency);
    const avr_cycle_count_t quantum = (avr_cycle_count_t)(atof(argv[3]) * 1e-6 * avr->frequency);
    const avr_cycle_count_t edge_gap = avr->frequency / 100000;
    int32_t count = 0;
    avr_raise_irq(pin_a, 1);
    avr_raise_irq(pin_b, 1);
    avr_raise_irq(adc0, 2500);
    avr_cycle_count_t next = quantum;
    while (next <= end) {
        if (run_until(avr, next) != 0) break;
        int8_t command = 0;
        if (avr->data[TCCR1A_ADDR] & (1 << COM1A1_BIT)) command = (avr->data[PORTD_ADDR] & (1 << DIR_BIT)) ? 1 : -1;
        int32_t state[2];
        if (full_io(1, &command, 1, 1) != 0 || full_io(0, state, sizeof state, 0) != 0) break;
        avr_raise_irq(adc0, (uint32_t)state[1]);
        while (count != state[0]) {
            count += state[0] > count ? 1 : -1;
            uint8_t ab = GRAY[(count + GRAY_AT_ZERO) & 3];
            avr_raise_irq(pin_a, (ab >> 1) & 1);
            avr_raise_irq(pin_b, ab & 1);
            if (run_until(avr, avr->cycle + edge_gap) != 0) break;
        }
        next += quantum;
    }
    fclose(uart);
    return 0;
}
