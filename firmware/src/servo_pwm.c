/*
 * servo_pwm.c — see servo_pwm.h (ATmega328P datasheet §16.9.3, fast PWM mode).
 */
#include "servo_pwm.h"

#include "pins.h"

#include <avr/io.h>
#include <util/atomic.h>

void servo_pwm_set(uint16_t ticks)
{
    ATOMIC_BLOCK(ATOMIC_RESTORESTATE)
    {
        OCR1B = ticks; /* 16-bit write through TEMP, shared with the capture ISR's ICR1 read */
    }
    SERVO_DDR |= _BV(SERVO_BIT);
}
