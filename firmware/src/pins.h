/*
 * pins.h — the hardware contract of the sensor head (ATmega328P, Arduino Uno/Nano at 16 MHz).
 *
 * The simavr board program that runs this firmware relies on every line of this file; change
 * nothing here without changing the board program too. Datasheet facts come from
 * shared/docs/sensor-facts.md and the ATmega328P datasheet (Microchip DS40002061).
 *
 *   function          pin   Arduino  notes
 *   UART0 RX          PD0   D0       115200 8N1, U2X, UBRR0 = 16 (117647 baud, +2.1 %)
 *   UART0 TX          PD1   D1
 *   SRF05 TRIG        PB1   D9       output, 12 us high pulse (datasheet: >= 10 us)
 *   SRF05 ECHO        PB0   D8       ICP1, Timer1 input capture, prescaler 8 = 0.5 us ticks
 *   stepper IN1..IN4  PD4-7 D4-D7    STEPPER=uln2003: half-step phases, one write to PORTD
 *   stepper STEP      PD4   D4       STEPPER=stepdir: one microstep per rising edge
 *   stepper DIR       PD5   D5       STEPPER=stepdir: high = counter-clockwise (angle increasing)
 *   stepper EN        PD6   D6       STEPPER=stepdir: low = enabled
 *   limit MIN         PB2   D10      PCINT2, active low, internal pull-up
 *   limit MAX         PB3   D11      PCINT3, active low, internal pull-up
 *   status LED        PB5   D13      on while a scan (or homing) is under way
 *
 * The servo head (make HEAD=servo) has no stepper and no switches; its servo takes PB2:
 *   servo signal      PB2   D10      OC1B, Timer1 fast PWM (mode 15, TOP = OCR1A): 50 Hz, 1-2 ms
 */
#ifndef SONAR_PINS_H
#define SONAR_PINS_H

/* UART0: 115200 baud with U2X. Datasheet baud-rate tables (sensor-facts.md): UBRR = 16 with U2X
 * gives 117647 baud (+2.1 %); without U2X the error would be -3.5 %. */
#define UART_BAUD 115200UL
#define UART_UBRR 16u
#define UART_U2X 1

/* SRF05 / HC-SR04 ranging module, SRF05 "mode 1" (separate trigger and echo pins, paper §II.A.1). */
#define SONAR_TRIG_DDR DDRB
#define SONAR_TRIG_PORT PORTB
#define SONAR_TRIG_BIT PB1 /* D9 */
#define SONAR_ECHO_DDR DDRB
#define SONAR_ECHO_PORT PORTB
#define SONAR_ECHO_PIN PINB
#define SONAR_ECHO_BIT PB0 /* D8 = ICP1 (datasheet §Timer/Counter1 input capture) */

/* Stepper on PORT D (the paper drives its ULN2003 from PORT D too, §II.A.2). */
#define STEPPER_DDR DDRD
#define STEPPER_PORT PORTD
#define STEPPER_MASK 0xF0u /* PD4..PD7; PD0..PD3 are never touched */
#define STEPPER_SHIFT 4    /* IN1 = PD4, IN2 = PD5, IN3 = PD6, IN4 = PD7 */
#define STEPDIR_STEP_BIT PD4 /* D4 */
#define STEPDIR_DIR_BIT PD5  /* D5, high = counter-clockwise */
#define STEPDIR_EN_BIT PD6   /* D6, low = enabled (A4988/DRV8825 ENABLE is active low) */

/* Limit switches on PORT B with the PORT B pin-change interrupt (the paper's PORT B interrupts). */
#define SWITCH_DDR DDRB
#define SWITCH_PORT PORTB
#define SWITCH_PIN PINB
#define SWITCH_MIN_BIT PB2 /* D10, PCINT2 */
#define SWITCH_MAX_BIT PB3 /* D11, PCINT3 */
#define SWITCH_PCMSK PCMSK0
#define SWITCH_PCIE PCIE0
#define SWITCH_MIN_PCINT PCINT2
#define SWITCH_MAX_PCINT PCINT3

/* Servo signal (HEAD=servo): OC1B, the Timer1 compare output that leaves ICP1 (the echo timing)
 * free: with TOP in OCR1A (mode 15), ICR1 still captures (datasheet §16.9.3). */
#define SERVO_DDR DDRB
#define SERVO_BIT PB2 /* D10 = OC1B */

/* Status LED (the Uno's "L" LED). */
#define LED_DDR DDRB
#define LED_PORT PORTB
#define LED_BIT PB5 /* D13 */

#endif
