/*
 * stepper.c — see stepper.h and pins.h.
 */
#include "stepper.h"

#include "config.h"
#include "motion.h"
#include "pins.h"

#include <avr/io.h>
#include <util/delay.h>

static bool released;

#if defined(CFG_STEPPER_ULN2003)

static uint8_t phase; /* 0..7, see motion_halfstep_pattern */

static void write_phase(uint8_t pattern)
{
    /* One write to PORTD: the four lines change together, PD0..PD3 keep their values. No ISR
     * writes PORTD, so the read-modify-write is safe. */
    STEPPER_PORT = (uint8_t)((STEPPER_PORT & (uint8_t)~STEPPER_MASK) |
                             (uint8_t)(pattern << STEPPER_SHIFT));
}

void stepper_init(void)
{
    phase = 0;
    write_phase(motion_halfstep_pattern(phase));
    STEPPER_DDR |= STEPPER_MASK;
    released = false;
}

void stepper_step(int8_t dir)
{
    phase = (uint8_t)((phase + (dir > 0 ? 1u : 7u)) & 7u);
    write_phase(motion_halfstep_pattern(phase));
    released = false;
}

void stepper_release(void)
{
    write_phase(0);
    released = true;
}

void stepper_energise(void)
{
    write_phase(motion_halfstep_pattern(phase));
    released = false;
}

#elif defined(CFG_STEPPER_STEPDIR)

void stepper_init(void)
{
    STEPPER_PORT &= (uint8_t)~(_BV(STEPDIR_STEP_BIT) | _BV(STEPDIR_DIR_BIT) | _BV(STEPDIR_EN_BIT));
    STEPPER_DDR |= _BV(STEPDIR_STEP_BIT) | _BV(STEPDIR_DIR_BIT) | _BV(STEPDIR_EN_BIT);
    released = false; /* EN low: enabled */
}

void stepper_step(int8_t dir)
{
    if (dir > 0) {
        STEPPER_PORT |= _BV(STEPDIR_DIR_BIT); /* high = counter-clockwise */
    } else {
        STEPPER_PORT &= (uint8_t)~_BV(STEPDIR_DIR_BIT);
    }
    _delay_us(STEPDIR_SETUP_US); /* DIR set-up before the STEP edge (A4988 200 ns, DRV8825 650 ns) */
    STEPPER_PORT |= _BV(STEPDIR_STEP_BIT);
    _delay_us(STEPDIR_PULSE_US); /* STEP high ≥ 1 µs (A4988), ≥ 1.9 µs (DRV8825) */
    STEPPER_PORT &= (uint8_t)~_BV(STEPDIR_STEP_BIT);
    released = false;
}

void stepper_release(void)
{
    STEPPER_PORT |= _BV(STEPDIR_EN_BIT); /* the translator keeps its microstep position */
    released = true;
}

void stepper_energise(void)
{
    STEPPER_PORT &= (uint8_t)~_BV(STEPDIR_EN_BIT);
    released = false;
}

#else
#error "set STEPPER (CFG_STEPPER_ULN2003 or CFG_STEPPER_STEPDIR)"
#endif

bool stepper_released(void)
{
    return released;
}
