/*
 * switches.c — debounce: the first closing edge counts at once; any change within
 * SWITCH_DEBOUNCE_MS (10 ms, sensor-facts: bounce 1–10 ms) after it is ignored.
 */
#include "switches.h"

#include "clock.h"
#include "config.h"
#include "motion.h"
#include "pins.h"

#include <avr/interrupt.h>
#include <avr/io.h>
#include <util/atomic.h>

static const uint8_t BITS[2] = {_BV(SWITCH_MIN_BIT), _BV(SWITCH_MAX_BIT)};

static volatile uint8_t closed_state; /* HEAD_SW_* bits, as last accepted */
static volatile uint8_t edges;        /* closing edges accepted since the last switches_take */
static volatile uint8_t locked;       /* HEAD_SW_* bits inside their debounce window */
static volatile uint16_t lock_ms[2];

static uint8_t raw_closed(void)
{
    uint8_t pins = SWITCH_PIN;
    uint8_t m = 0;
    if (!(pins & BITS[0])) {
        m |= HEAD_SW_MIN;
    }
    if (!(pins & BITS[1])) {
        m |= HEAD_SW_MAX;
    }
    return m;
}

ISR(PCINT0_vect)
{
    uint8_t now_closed = raw_closed();
    uint16_t now = clock_ms16_isr();
    for (uint8_t i = 0; i < 2; i++) {
        uint8_t bit = (uint8_t)(1u << i);
        if ((locked & bit) && (uint16_t)(now - lock_ms[i]) < SWITCH_DEBOUNCE_MS) {
            continue; /* bounce */
        }
        locked &= (uint8_t)~bit;
        if ((now_closed ^ closed_state) & bit) {
            closed_state ^= bit;
            if (now_closed & bit) {
                edges |= bit;
                locked |= bit;
                lock_ms[i] = now;
            }
        }
    }
}

void switches_init(void)
{
    SWITCH_DDR &= (uint8_t)~(_BV(SWITCH_MIN_BIT) | _BV(SWITCH_MAX_BIT));
    SWITCH_PORT |= _BV(SWITCH_MIN_BIT) | _BV(SWITCH_MAX_BIT); /* internal pull-ups */
    closed_state = raw_closed();
    edges = 0;
    locked = 0;
    SWITCH_PCMSK |= _BV(SWITCH_MIN_PCINT) | _BV(SWITCH_MAX_PCINT);
    PCIFR = _BV(PCIF0);
    PCICR |= _BV(SWITCH_PCIE);
}

uint8_t switches_closed(void)
{
    uint8_t m;
    ATOMIC_BLOCK(ATOMIC_RESTORESTATE)
    {
        /* Inside the debounce window the accepted state holds; after it, the pin itself (an
         * edge may have been swallowed by the window). */
        uint16_t now = clock_ms16_isr();
        uint8_t raw = raw_closed();
        for (uint8_t i = 0; i < 2; i++) {
            uint8_t bit = (uint8_t)(1u << i);
            if ((locked & bit) && (uint16_t)(now - lock_ms[i]) >= SWITCH_DEBOUNCE_MS) {
                locked &= (uint8_t)~bit;
            }
            if (!(locked & bit)) {
                closed_state = (uint8_t)((closed_state & (uint8_t)~bit) | (raw & bit));
            }
        }
        m = closed_state;
    }
    return m;
}

uint8_t switches_take(void)
{
    uint8_t level = switches_closed();
    uint8_t e;
    ATOMIC_BLOCK(ATOMIC_RESTORESTATE)
    {
        e = edges;
        edges = 0;
    }
    return (uint8_t)(level | e);
}
