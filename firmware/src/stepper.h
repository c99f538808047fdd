/*
 * stepper.h — one microstep at a time, on a ULN2003 (half steps, four phase lines) or a STEP/DIR
 * driver (A4988/DRV8825), chosen at build time (STEPPER=uln2003|stepdir). Timing is the caller's.
 */
#ifndef SONAR_STEPPER_H
#define SONAR_STEPPER_H

#include <stdbool.h>
#include <stdint.h>

void stepper_init(void);
/* One microstep: dir +1 counter-clockwise (angle increasing), −1 clockwise. */
void stepper_step(int8_t dir);
/* Coils off (ULN2003: all four lines low; STEP/DIR: EN high). */
void stepper_release(void);
/* Coils on again at the same phase; the caller waits a step interval before stepping. */
void stepper_energise(void);
bool stepper_released(void);

#endif
