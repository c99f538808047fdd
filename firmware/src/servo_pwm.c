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
        /* Fast PWM keeps OC1B high from BOTTOM through the compare match: OCR1B + 1 ticks
         * (datasheet §16.9.3). A 16-bit write through TEMP, shared with the capture ISR. */
        OCR1B = ticks - 1u;
    }
    SERVO_DDR |= _BV(SERVO_BIT);
}
