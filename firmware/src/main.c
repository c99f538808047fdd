/*
 * main.c — the sensor head's firmware for the ATmega328P (Arduino Uno/Nano, 16 MHz).
 *
 * The paper's head ran on a PIC16F877A; this is the same head on an ATmega328P, speaking
 * docs/protocol.md version 2 and behaving on the wire like simulator/src/firmware.rs. The
 * decisions live in motion.c (pure); this file wires them to the hardware and keeps the timing:
 * a step interval after each microstep, SETTLE_MS before a ping, PING_INTERVAL_MS between
 * triggers. Nothing here waits for input: the loop polls and moves on.
 *
 * The servo head (HEAD=servo) links servo.c instead of motion.c (the same head interface) and
 * runs its own loop: a move to the next ping's angle, its settle time, the ping.
 */
#include "clock.h"
#include "compat.h"
#include "config.h"
#include "head_id.h"
#include "pins.h"
#include "protocol.h"
#include "sonar.h"
#include "uart.h"
#if defined(CFG_HEAD_SERVO)
#include "servo.h"
#include "servo_pwm.h"
#else
#include "motion.h"
#include "stepper.h"
#include "switches.h"
#endif

#include <avr/interrupt.h>
#include <avr/io.h>
#include <avr/wdt.h>

#if defined(SIMAVR_MCU_SECTION_H)
/* Tags the ELF for simavr (a .mmcu section, which the .hex leaves out). */
#include SIMAVR_MCU_SECTION_H
AVR_MCU(F_CPU, "atmega328p");
#endif

/* ---- reset cause, before anything else ------------------------------------------------------- */

/* MCUSR as found at reset. Optiboot clears MCUSR before starting the sketch but passes its value
 * in r2; older bootloaders leave MCUSR alone. */
uint8_t reset_cause __attribute__((section(".noinit")));

void early_init(void) __attribute__((naked, used, section(".init3")));
void early_init(void)
{
    uint8_t r2;
    __asm__ __volatile__("mov %0, r2" : "=r"(r2));
    uint8_t cause = MCUSR;
    reset_cause = cause ? cause : r2;
    /* Clear the flags and stop the watchdog at once: after a watchdog reset it keeps running at
     * its shortest period, and an old bootloader would reset forever. */
    MCUSR = 0;
    wdt_disable();
}

/* ---- output ---------------------------------------------------------------------------------- */

static void send(void *ctx, const dev_msg *m)
{
    (void)ctx;
    static char line[PROTO_OUT_CAP];
    uint8_t n = proto_encode(m, line);
    uart_write(line, n);
}

static head_t head;
static char head_id[HEAD_ID_HEX_LEN + 1];
static proto_framer framer;

static void send_err_P(uint8_t code, const char *text_P)
{
    dev_msg m;
    proto_err_P(&m, code, text_P);
    send(0, &m);
}

/* ---- input ----------------------------------------------------------------------------------- */

static void service_rx(void)
{
    uint8_t b;
    while (uart_read(&b)) {
        switch (proto_framer_push(&framer, b)) {
        case FRAME_LINE: {
            proto_cmd cmd;
            dev_msg m;
            uint8_t code = proto_parse_command(framer.buf, framer.line_len, &cmd, m.u.err.text);
            if (code == ERR_NONE) {
                head_command(&head, &cmd);
            } else {
                m.kind = MSG_ERR;
                m.u.err.code = code;
                send(0, &m);
            }
            break;
        }
        case FRAME_OVERFLOW:
            send_err_P(ERR_SYNTAX, FSTR("line too long"));
            break;
        default:
            break;
        }
    }
}

/* ---- the loop -------------------------------------------------------------------------------- */

/* Whether a ping is under way; its result, once in, goes to the head. Both heads' loops do
 * nothing else until it is. */
static bool ping_in_flight(void)
{
    if (!sonar_busy()) {
        return false;
    }
    sonar_result r;
    if (sonar_poll(&r)) {
        head_ping_done(&head, r.echo_us, r.silent, clock_ms());
    }
    return true;
}

static void led(bool on)
{
    if (on) {
        LED_PORT |= _BV(LED_BIT);
    } else {
        LED_PORT &= (uint8_t)~_BV(LED_BIT);
    }
}

#if defined(CFG_HEAD_SERVO)
int main(void)
{
    LED_DDR |= _BV(LED_BIT);
    clock_init();
    uart_init();
    proto_framer_init(&framer);
    sei();

    head_id_load(head_id); /* ≈ 1 s at the very first boot only */
    sonar_init();          /* Timer1: the echo timing and the servo's PWM */
    head_init(&head, head_id, send, 0);

    /* docs/protocol.md: after power-on or any reset the device sends its HELLO by itself. */
    head_send_hello(&head);
    if (reset_cause & _BV(WDRF)) {
        send_err_P(ERR_HARDWARE, FSTR("watchdog reset"));
    }
    wdt_enable(WDTO_500MS);

    uint32_t moved_us = clock_us(); /* when the last move was commanded */
    uint32_t settle_us = 0;         /* how long that move needs before a ping */
    uint32_t last_trigger_us = moved_us - PING_INTERVAL_MS * 1000UL;

    for (;;) {
        wdt_reset();
        service_rx();
        uint32_t now = clock_us();

        if (ping_in_flight()) {
            continue;
        }
        uint8_t action = head_next(&head);
        led(head_busy(&head));
        if (action == HEAD_ACT_MOVE) {
            servo_pwm_set(servo_pulse_ticks_of_head(head_angle_cdeg(&head)));
            moved_us = now;
            settle_us = head.settle * 1000UL;
        } else if (action == HEAD_ACT_PING && now - moved_us >= settle_us &&
                   now - last_trigger_us >= PING_INTERVAL_MS * 1000UL + 2 * CLOCK_US_RESOLUTION) {
            /* The clock has 8 µs steps: the margin keeps the ping interval for sure. */
            last_trigger_us = clock_us();
            sonar_trigger();
        }
    }
}
#else
int main(void)
{
    LED_DDR |= _BV(LED_BIT);
    clock_init();
    uart_init();
    switches_init();
    stepper_init();
    proto_framer_init(&framer);
    sei();

    head_id_load(head_id); /* ≈ 1 s at the very first boot only */
    sonar_init();
    head_init(&head, &MOTOR_RATIO, head_id, send, 0);

    /* docs/protocol.md: after power-on or any reset the device sends its HELLO by itself. */
    head_send_hello(&head);
    if (reset_cause & _BV(WDRF)) {
        send_err_P(ERR_HARDWARE, FSTR("watchdog reset"));
    }
    wdt_enable(WDTO_500MS);

    uint32_t last_step_us = clock_us();
    uint32_t last_trigger_us = last_step_us - PING_INTERVAL_MS * 1000UL;
    uint32_t idle_since_us = last_step_us;
    bool step_pending = false; /* a microstep was made; its interval has not run out */
    int8_t step_dir = 0;       /* direction of that microstep */

    for (;;) {
        wdt_reset();
        service_rx();
        uint32_t now = clock_us();

        if (ping_in_flight()) {
            continue;
        }
        if (step_pending) {
            if (now - last_step_us < STEP_INTERVAL_US) {
                continue;
            }
            step_pending = false;
            if (step_dir != 0) {
                /* The step has had its interval: is the switch ahead closed now? */
                head_check_switches(&head, switches_take(), step_dir);
            }
        }

        uint8_t action = head_next(&head);
        led(head_busy(&head));
        switch (action) {
        case HEAD_ACT_STEP:
            if (head_check_switches(&head, switches_take(), head.step_dir)) {
                break; /* the switch ahead is already closed */
            }
            if (stepper_released()) {
                stepper_energise(); /* same phase as before; move one interval later */
                step_dir = 0;
            } else {
                stepper_step(head.step_dir);
                head_stepped(&head);
                step_dir = head.step_dir;
            }
            step_pending = true;
            last_step_us = now;
            idle_since_us = now;
            break;
        case HEAD_ACT_PING:
            idle_since_us = now;
            if (stepper_released()) {
                stepper_energise(); /* hold the head while it pings; settle first */
                last_step_us = now;
                break;
            }
            /* The clock has 8 µs steps: the margin keeps ≥ 50 ms between triggers for sure. */
            if (now - last_step_us >= SETTLE_MS * 1000UL &&
                now - last_trigger_us >= PING_INTERVAL_MS * 1000UL + 2 * CLOCK_US_RESOLUTION) {
                last_trigger_us = clock_us();
                sonar_trigger();
            }
            break;
        default:
            /* Standing still: only both switches closed at once means something (a fault). */
            (void)head_check_switches(&head, switches_take(), 0);
            if (DEENERGISE_IDLE_MS != 0 && !stepper_released() &&
                now - idle_since_us >= DEENERGISE_IDLE_MS * 1000UL) {
                stepper_release();
            }
            break;
        }
    }
}
#endif
