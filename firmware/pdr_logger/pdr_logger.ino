/* pdr_logger: the paper's pinion-double-rack rig on an Arduino UNO (ATmega328P), logging what the pdr
 * pipeline reads (docs/FORMAT.md's format): one line `t_ms,counts,adc,dir` per control loop, header first.
 *
 * Each loop, on a millis() schedule that does not drift (the next instant is the last one plus the
 * period, not "now" plus the period): sample millis(), the encoder count and the ACS712; decide the
 * command with the sampled guard (pdr_controller.h, the same code the host test holds against the
 * model); apply it; print the line with the command just decided.  For the first LEAD_IN_MS the motor
 * stays off (dir 0), so the current sensor's zero can be read at rest (zero_v = "auto").
 *
 * Build and flash: `make firmware` (docs/RIG.md), or open this folder in the Arduino IDE. */

#include <Arduino.h>
#include "pdr_controller.h"

/* ---- Settings, named as the rig TOML names them.  The matching raw/<name>.toml:
 *
 *   [encoder]
 *   counts_per_rev = 6533.12          # COUNTS_PER_REV
 *   [current_sensor]
 *   sensitivity_v_per_a = 0.185       # ACS712-05B
 *   zero_v = "auto"                   # estimated from the lead-in's rows at rest
 *   adc_vref = 5.0
 *   adc_steps = 1024
 *   [drive]
 *   v_in = 6.0                        # supply 12 V at PWM_DUTY_PERCENT 25, as RMS 12 * sqrt(0.25)
 *   [controller]
 *   period_s = 0.05                   # PERIOD_MS / 1000
 *   guard_rad = 0.9424777960769379    # 0.15 rev: GUARD_COUNTS = ceil(guard_rad * counts_per_rev / (2 pi))
 *
 * Change a setting here and change its key there. ---- */
static const uint32_t BAUD = 115200;             /* a line (<= 34 bytes) takes < 3 ms of the period */
static const uint32_t PERIOD_MS = 50;            /* controller.period_s = 0.05 */
static const int32_t GUARD_COUNTS = 980;         /* controller.guard_rad = 0.15 rev in counts, rounded up */
static const float COUNTS_PER_REV = 6533.12f;    /* encoder.counts_per_rev: 64 CPR x4 decoding x 102.08 */
static const uint8_t PWM_DUTY_PERCENT = 25;      /* drive.v_in = supply * sqrt(duty) (MODEL.md's V_in) */
static const uint32_t LEAD_IN_MS = 1000;         /* motor off (dir 0) from the first sample for this long */
static const int8_t FIRST_DIR = PDR_DIR_Q1;      /* the first command after the lead-in decides from q1 */

static const uint8_t ENCODER_A_PIN = 2;          /* INT0: encoder channel A */
static const uint8_t ENCODER_B_PIN = 3;          /* INT1: encoder channel B */
static const uint8_t CURRENT_SENSOR_PIN = A0;    /* ACS712 OUT */
static const uint8_t DRIVE_DIR_PIN = 7;          /* H-bridge direction: HIGH = q1 (+v_in) */
static const uint8_t DRIVE_PWM_PIN = 9;          /* H-bridge enable / PWM (timer 1, 490 Hz) */
/* ---- end of settings ---- */

static const uint8_t PWM_VALUE = (uint8_t)((255u * PWM_DUTY_PERCENT + 50u) / 100u);
static const uint32_t LEAD_IN_SAMPLES = (LEAD_IN_MS + PERIOD_MS - 1) / PERIOD_MS;

static volatile int32_t encoder_counts = 0;      /* written by the pin-change interrupts only */
static volatile uint8_t encoder_ab = 0;          /* the channels' last state, A << 1 | B */
static volatile uint8_t *encoder_a_in, *encoder_b_in;
static uint8_t encoder_a_mask, encoder_b_mask;

static uint32_t next_sample_ms;
static uint32_t samples = 0;
static int8_t dir = PDR_DIR_OFF;

static uint8_t encoder_state(void)
{
    return (uint8_t)(((*encoder_a_in & encoder_a_mask) ? 2 : 0) | ((*encoder_b_in & encoder_b_mask) ? 1 : 0));
}

/* Either channel changed: x4 decoding by the state table (a double step, a missed edge, counts 0). */
static void on_encoder_edge(void)
{
    uint8_t ab = encoder_state();
    encoder_counts += PDR_QUADRATURE_STEP[(encoder_ab << 2) | ab];
    encoder_ab = ab;
}

/* The count, read with interrupts held off: a 32-bit read is four byte reads an edge could split. */
static int32_t encoder_counts_now(void)
{
    noInterrupts();
    int32_t c = encoder_counts;
    interrupts();
    return c;
}

static void drive(int8_t command)
{
    digitalWrite(DRIVE_DIR_PIN, command >= 0 ? HIGH : LOW);
    analogWrite(DRIVE_PWM_PIN, command == PDR_DIR_OFF ? 0 : PWM_VALUE);
}

void setup()
{
    drive(PDR_DIR_OFF);
    pinMode(DRIVE_DIR_PIN, OUTPUT);
    pinMode(DRIVE_PWM_PIN, OUTPUT);
    pinMode(ENCODER_A_PIN, INPUT_PULLUP);
    pinMode(ENCODER_B_PIN, INPUT_PULLUP);
    encoder_a_in = portInputRegister(digitalPinToPort(ENCODER_A_PIN));
    encoder_b_in = portInputRegister(digitalPinToPort(ENCODER_B_PIN));
    encoder_a_mask = digitalPinToBitMask(ENCODER_A_PIN);
    encoder_b_mask = digitalPinToBitMask(ENCODER_B_PIN);
    encoder_ab = encoder_state();
    attachInterrupt(digitalPinToInterrupt(ENCODER_A_PIN), on_encoder_edge, CHANGE);
    attachInterrupt(digitalPinToInterrupt(ENCODER_B_PIN), on_encoder_edge, CHANGE);

    Serial.begin(BAUD);
    Serial.print(F("# pdr_logger period_ms="));
    Serial.print(PERIOD_MS);
    Serial.print(F(" guard_counts="));
    Serial.print(GUARD_COUNTS);
    Serial.print(F(" counts_per_rev="));
    Serial.print(COUNTS_PER_REV, 2);
    Serial.print(F(" pwm_duty_percent="));
    Serial.print(PWM_DUTY_PERCENT);
    Serial.print(F(" lead_in_ms="));
    Serial.print(LEAD_IN_MS);
    Serial.print(F("\nt_ms,counts,adc,dir\n"));
    next_sample_ms = millis();
}

void loop()
{
    while ((int32_t)(millis() - next_sample_ms) < 0) {
    }
    uint32_t t_ms = millis();
    next_sample_ms += PERIOD_MS;
    int32_t counts = encoder_counts_now();
    int adc = analogRead(CURRENT_SENSOR_PIN);
    dir = pdr_command(dir, samples, LEAD_IN_SAMPLES, counts, GUARD_COUNTS, FIRST_DIR);
    if (samples < LEAD_IN_SAMPLES) {
        samples++;                               /* counted as far as it matters: no wrap after 49.7 days */
    }
    drive(dir);
    Serial.print(t_ms);
    Serial.print(',');
    Serial.print(counts);
    Serial.print(',');
    Serial.print(adc);
    Serial.print(',');
    Serial.print(dir);
    Serial.print('\n');
}
