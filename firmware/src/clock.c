/*
 * clock.c — Timer2 CTC 1 kHz (ATmega328P datasheet §Timer/Counter2: CTC mode, WGM21; OCR2A = 124
 * with prescaler 128 gives 16 MHz / 128 / 125 = 1000 Hz).
 */
#include "clock.h"

#include <avr/interrupt.h>
#include <avr/io.h>
#include <util/atomic.h>

#define T2_TOP 124u       /* 125 counts per ms */
#define T2_US_PER_COUNT CLOCK_US_RESOLUTION /* 128 / 16 MHz */

static volatile uint32_t ms_count;

ISR(TIMER2_COMPA_vect)
{
    ms_count++;
}

void clock_init(void)
{
    TCCR2A = _BV(WGM21);             /* CTC, TOP = OCR2A */
    TCCR2B = _BV(CS22) | _BV(CS20); /* clk / 128 */
    OCR2A = T2_TOP;
    TCNT2 = 0;
    TIFR2 = _BV(OCF2A);
    TIMSK2 = _BV(OCIE2A);
}

uint32_t clock_ms(void)
{
    uint32_t v;
    ATOMIC_BLOCK(ATOMIC_RESTORESTATE)
    {
        v = ms_count;
    }
    return v;
}

uint32_t clock_us(void)
{
    uint32_t ms;
    uint8_t count;
    ATOMIC_BLOCK(ATOMIC_RESTORESTATE)
    {
        ms = ms_count;
        count = TCNT2;
        /* A compare match not yet serviced: the counter restarted, the ms is not counted yet. */
        if ((TIFR2 & _BV(OCF2A)) && count < T2_TOP) {
            ms++;
        }
    }
    return ms * 1000u + (uint32_t)count * T2_US_PER_COUNT;
}

uint16_t clock_ms16_isr(void)
{
    return (uint16_t)ms_count;
}
