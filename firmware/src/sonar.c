/*
 * sonar.c — echo timing on Timer1 (ATmega328P datasheet §Timer/Counter1: input capture unit).
 *
 * Timer1 free-runs at 16 MHz / 8 = 2 MHz (0.5 µs ticks) and wraps every 32.8 ms; its overflow
 * interrupt extends it to 32 bits. The capture interrupt timestamps the rising edge of ECHO, flips
 * ICES1 to catch the falling edge, and timestamps that. The main loop polls for the end and
 * applies the timeouts (sensor-facts: SRF05 drops ECHO after ≈ 30 ms without an echo, HC-SR04
 * after ≈ 38 ms).
 *
 * The servo head (HEAD=servo) shares Timer1 with its servo: fast PWM with TOP = OCR1A = 39999
 * (mode 15), so the count wraps every 20 ms (the servo's 50 Hz frame) and OC1B makes the pulse.
 * Input capture still works in that mode (only ICR1 as TOP disables it); the extension to 32 bits
 * adds 40000 per wrap instead of 65536.
 */
#include "sonar.h"

#include "config.h"
#include "pins.h"

#include <avr/interrupt.h>
#include <avr/io.h>
#include <util/atomic.h>
#include <util/delay.h>

#define TICKS_PER_MS 2000UL /* 16 MHz / 8 */
#if defined(CFG_HEAD_SERVO)
#define T1_PERIOD (SERVO_PERIOD_US * 2UL) /* 40000 ticks = 20 ms */
#else
#define T1_PERIOD 0x10000UL
#endif

enum { S_IDLE = 0, S_WAIT_RISE, S_WAIT_FALL, S_DONE };

static volatile uint32_t t1_base; /* ticks counted by the wraps so far */
static volatile uint8_t state;
static volatile uint32_t rise_ticks;
static volatile uint32_t width_ticks;
static uint32_t trigger_ticks;

ISR(TIMER1_OVF_vect)
{
    t1_base += T1_PERIOD;
}

/* 32-bit timestamp of a 16-bit count read now; an overflow pending but not yet counted belongs
 * to a small count. Interrupts are off (ISR or atomic block). */
static uint32_t extend(uint16_t count)
{
    uint32_t base = t1_base;
    if ((TIFR1 & _BV(TOV1)) && count < T1_PERIOD / 2u) {
        base += T1_PERIOD;
    }
    return base + count;
}

ISR(TIMER1_CAPT_vect)
{
    uint16_t icr = ICR1;
    uint32_t ts = extend(icr);
    if (state == S_WAIT_RISE) {
        rise_ticks = ts;
        TCCR1B &= (uint8_t)~_BV(ICES1); /* now the falling edge */
        TIFR1 = _BV(ICF1);              /* datasheet: clear ICF1 after changing the edge */
        state = S_WAIT_FALL;
    } else if (state == S_WAIT_FALL) {
        width_ticks = ts - rise_ticks;
        TCCR1B |= _BV(ICES1);
        TIFR1 = _BV(ICF1);
        state = S_DONE;
    }
}

void sonar_init(void)
{
    SONAR_TRIG_DDR |= _BV(SONAR_TRIG_BIT);
    SONAR_TRIG_PORT &= (uint8_t)~_BV(SONAR_TRIG_BIT);
    SONAR_ECHO_DDR &= (uint8_t)~_BV(SONAR_ECHO_BIT);
    SONAR_ECHO_PORT &= (uint8_t)~_BV(SONAR_ECHO_BIT); /* no pull-up: the module drives ECHO */
#if defined(CFG_HEAD_SERVO)
    /* Mode 15 (WGM13..10 = 1111), TOP = OCR1A; OC1B clears on compare match, sets at BOTTOM. */
    OCR1A = (uint16_t)(T1_PERIOD - 1u);
    TCCR1A = _BV(COM1B1) | _BV(WGM11) | _BV(WGM10);
    TCCR1B = _BV(ICNC1) | _BV(ICES1) | _BV(WGM13) | _BV(WGM12) | _BV(CS11);
#else
    TCCR1A = 0;                                        /* normal mode */
    TCCR1B = _BV(ICNC1) | _BV(ICES1) | _BV(CS11);      /* noise canceller, rising edge, clk/8 */
#endif
    TIFR1 = _BV(ICF1) | _BV(TOV1);
    TIMSK1 = _BV(ICIE1) | _BV(TOIE1);
    state = S_IDLE;
}

uint32_t sonar_ticks(void)
{
    uint32_t v;
    ATOMIC_BLOCK(ATOMIC_RESTORESTATE)
    {
        v = extend(TCNT1);
    }
    return v;
}

void sonar_trigger(void)
{
    ATOMIC_BLOCK(ATOMIC_RESTORESTATE)
    {
        TCCR1B |= _BV(ICES1);
        TIFR1 = _BV(ICF1);
        state = S_WAIT_RISE;
    }
    trigger_ticks = sonar_ticks();
    /* sensor-facts / paper §II.A.1: TRIG high ≥ 10 µs; the module then sends 8 cycles at 40 kHz. */
    SONAR_TRIG_PORT |= _BV(SONAR_TRIG_BIT);
    _delay_us(SONAR_TRIG_PULSE_US);
    SONAR_TRIG_PORT &= (uint8_t)~_BV(SONAR_TRIG_BIT);
}

bool sonar_busy(void)
{
    return state != S_IDLE;
}

bool sonar_poll(sonar_result *out)
{
    uint8_t s;
    uint32_t rise, width;
    ATOMIC_BLOCK(ATOMIC_RESTORESTATE)
    {
        s = state;
        rise = rise_ticks;
        width = width_ticks;
    }
    uint32_t now = sonar_ticks();
    out->silent = false;
    out->echo_us = 0;
    switch (s) {
    case S_WAIT_RISE:
        if (now - trigger_ticks < SONAR_RISE_TIMEOUT_MS * TICKS_PER_MS) {
            return false;
        }
        out->silent = true; /* the echo line never rose: module silent or missing */
        break;
    case S_WAIT_FALL:
        if (now - rise < SONAR_FALL_TIMEOUT_MS * TICKS_PER_MS) {
            return false;
        }
        break; /* no falling edge within 32 ms: no echo */
    case S_DONE: {
        uint32_t us = (width + 1u) / 2u;
        if (us < SONAR_NO_ECHO_US) {
            out->echo_us = (uint16_t)us;
        }
        break; /* ≥ 28 ms: the module's no-echo timeout */
    }
    default:
        return false;
    }
    ATOMIC_BLOCK(ATOMIC_RESTORESTATE)
    {
        state = S_IDLE;
        TCCR1B |= _BV(ICES1);
    }
    return true;
}
