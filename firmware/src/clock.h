/*
 * clock.h — the device clock: Timer2 in CTC mode at 1 kHz (16 MHz / 128 / 125), plus a µs
 * reading that adds the Timer2 count (8 µs per count). Both wrap (49.7 days, 71.6 minutes):
 * compare times only by unsigned difference.
 */
#ifndef SONAR_CLOCK_H
#define SONAR_CLOCK_H

#include <stdint.h>

/* clock_us() counts in steps of this many µs. */
#define CLOCK_US_RESOLUTION 8u

void clock_init(void);
/* Milliseconds since power-on (the RD time_ms). */
uint32_t clock_ms(void);
/* Microseconds since power-on, 8 µs resolution. */
uint32_t clock_us(void);
/* The low 16 bits of the ms counter, for use inside ISRs (interrupts already off). */
uint16_t clock_ms16_isr(void);

#endif
