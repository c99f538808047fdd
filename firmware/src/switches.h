/*
 * switches.h — the two limit switches on PORT B's pin-change interrupt (the paper's PORT B
 * interrupts), active low with the internal pull-ups. The ISR only records; the main loop acts.
 */
#ifndef SONAR_SWITCHES_H
#define SONAR_SWITCHES_H

#include <stdint.h>

void switches_init(void);
/* Mask (HEAD_SW_MIN | HEAD_SW_MAX) of the switches closed now, or closed by an edge since the
 * previous call (a short closing counts even if it has opened again). */
uint8_t switches_take(void);
/* Mask of the switches closed now (debounced level), without consuming edges. */
uint8_t switches_closed(void);

#endif
