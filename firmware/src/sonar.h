/*
 * sonar.h — the SRF05 / HC-SR04 ranging module: TRIG pulse, echo pulse width measured with Timer1
 * input capture (ICP1), prescaler 8 → 0.5 µs ticks, rising edge then falling edge, no busy-wait.
 */
#ifndef SONAR_SONAR_H
#define SONAR_SONAR_H

#include <stdbool.h>
#include <stdint.h>

typedef struct {
    uint16_t echo_us; /* time of flight, µs; 0 = no echo */
    bool silent;      /* the echo line never rose after the trigger */
} sonar_result;

/* Timer1: normal mode, clk/8, input capture with noise canceller, overflow counting. */
void sonar_init(void);
/* Fires one ping (a 12 µs TRIG pulse, the only short busy-wait). */
void sonar_trigger(void);
/* Whether a ping is under way. */
bool sonar_busy(void);
/* Call often while busy: true once the ping is over, with its result. */
bool sonar_poll(sonar_result *out);
/* Timer1's extended 32-bit count (0.5 µs ticks), for entropy and tests. */
uint32_t sonar_ticks(void);

#endif
