/*
 * servo_pwm.h — the servo's signal on OC1B (PB2, D10): Timer1, set up by sonar_init in the servo
 * build (fast PWM, 50 Hz, 0.5 µs ticks), makes the pulse in hardware; this only sets its width.
 */
#ifndef SONAR_SERVO_PWM_H
#define SONAR_SERVO_PWM_H

#include <stdint.h>

/* The pulse width from the next 20 ms frame on (OCR1B is double-buffered: no short pulse), in
 * Timer1 ticks of 0.5 µs (servo_pulse_ticks, ≥ 1). The first call switches the output on: until then
 * the servo gets no pulse and holds nothing. Call after sonar_init. */
void servo_pwm_set(uint16_t ticks);

#endif
