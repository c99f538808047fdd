/*
 * head_id.c — see head_id.h.
 *
 * Entropy: the watchdog runs from its own 128 kHz RC oscillator, independent of the 16 MHz
 * crystal; sampling Timer1 (at 16 MHz) in each watchdog interrupt gives counts whose low bits
 * jitter (the well-known WDT-jitter technique of the Arduino "Entropy" library). 64 samples
 * are mixed with Jenkins' one-at-a-time hash into two 32-bit lanes.
 */
#include "head_id.h"

#include "protocol.h"

void head_id_pool_init(head_id_pool *p)
{
    p->h[0] = 0x6A09E667UL; /* any distinct non-zero seeds */
    p->h[1] = 0xBB67AE85UL;
    p->n = 0;
}

static uint32_t oaat_step(uint32_t h, uint8_t byte)
{
    h += byte;
    h += h << 10;
    h ^= h >> 6;
    return h;
}

static uint32_t oaat_final(uint32_t h)
{
    h += h << 3;
    h ^= h >> 11;
    h += h << 15;
    return h;
}

void head_id_pool_add(head_id_pool *p, uint16_t sample)
{
    /* Every sample goes into both lanes (low byte carries the jitter; the high byte costs
     * nothing); the lanes differ by their seeds and by the order of the bytes. */
    p->h[0] = oaat_step(oaat_step(p->h[0], (uint8_t)sample), (uint8_t)(sample >> 8));
    p->h[1] = oaat_step(oaat_step(p->h[1], (uint8_t)(sample >> 8)), (uint8_t)sample);
    p->h[1] = oaat_step(p->h[1], (uint8_t)(p->h[0] >> 24));
    p->n++;
}

void head_id_pool_finish(head_id_pool *p, uint8_t id[HEAD_ID_BYTES])
{
    uint32_t a = oaat_final(oaat_step(p->h[0], (uint8_t)p->h[1]));
    uint32_t b = oaat_final(oaat_step(p->h[1], (uint8_t)a));
    for (uint8_t i = 0; i < 4; i++) {
        id[i] = (uint8_t)(a >> (24 - 8 * i));
        id[4 + i] = (uint8_t)(b >> (24 - 8 * i));
    }
}

bool head_id_record_valid(const uint8_t rec[HEAD_ID_RECORD])
{
    uint16_t crc = proto_crc16(rec, HEAD_ID_BYTES);
    return rec[HEAD_ID_BYTES] == (uint8_t)(crc >> 8) && rec[HEAD_ID_BYTES + 1] == (uint8_t)crc;
}

void head_id_make_record(uint8_t rec[HEAD_ID_RECORD], const uint8_t id[HEAD_ID_BYTES])
{
    for (uint8_t i = 0; i < HEAD_ID_BYTES; i++) {
        rec[i] = id[i];
    }
    uint16_t crc = proto_crc16(id, HEAD_ID_BYTES);
    rec[HEAD_ID_BYTES] = (uint8_t)(crc >> 8); /* big-endian */
    rec[HEAD_ID_BYTES + 1] = (uint8_t)crc;
}

void head_id_hex(const uint8_t id[HEAD_ID_BYTES], char out[HEAD_ID_HEX_LEN + 1])
{
    static const char HEX[] = "0123456789ABCDEF";
    for (uint8_t i = 0; i < HEAD_ID_BYTES; i++) {
        out[2 * i] = HEX[id[i] >> 4];
        out[2 * i + 1] = HEX[id[i] & 0xFu];
    }
    out[HEAD_ID_HEX_LEN] = '\0';
}

#if defined(__AVR__)

#include "clock.h"

#include <avr/eeprom.h>
#include <avr/interrupt.h>
#include <avr/io.h>
#include <avr/wdt.h>
#include <util/atomic.h>

static volatile uint16_t wdt_sample;
static volatile bool wdt_fired;

ISR(WDT_vect)
{
    wdt_sample = TCNT1;
    wdt_fired = true;
    /* Interrupt-only mode keeps WDIE set on the chip; simavr clears it after each interrupt (as
     * the chip does in interrupt-and-reset mode). Setting it again needs no timed sequence. */
    WDTCSR |= _BV(WDIE);
}

static void make_id(uint8_t id[HEAD_ID_BYTES])
{
    head_id_pool pool;
    head_id_pool_init(&pool);
    TCCR1A = 0;
    TCCR1B = _BV(CS10); /* Timer1 at 16 MHz: one count per CPU clock */
    ATOMIC_BLOCK(ATOMIC_RESTORESTATE)
    {
        wdt_reset();
        /* Watchdog in interrupt mode only (WDIE, no WDE), shortest period (16 ms): datasheet
         * §Watchdog Timer, timed sequence with WDCE. */
        WDTCSR = _BV(WDCE) | _BV(WDE);
        WDTCSR = _BV(WDIE);
    }
    for (uint8_t i = 0; i < HEAD_ID_ENTROPY_SAMPLES; i++) {
        /* One watchdog period is 16 ms; should an interrupt not come (a simulator without the
         * watchdog), take Timer1 as it is after 40 ms rather than hang. */
        uint32_t start = clock_ms();
        while (!wdt_fired && clock_ms() - start < 40u) {
        }
        uint16_t sample;
        ATOMIC_BLOCK(ATOMIC_RESTORESTATE)
        {
            sample = wdt_fired ? wdt_sample : TCNT1;
            wdt_fired = false;
        }
        head_id_pool_add(&pool, sample);
    }
    wdt_disable();
    TCCR1B = 0;
    head_id_pool_finish(&pool, id);
}

void head_id_load(char out[HEAD_ID_HEX_LEN + 1])
{
    uint8_t rec[HEAD_ID_RECORD];
    eeprom_read_block(rec, (const void *)EE_HEAD_ID_ADDR, HEAD_ID_RECORD);
    if (!head_id_record_valid(rec)) {
        uint8_t id[HEAD_ID_BYTES];
        make_id(id); /* needs interrupts on */
        head_id_make_record(rec, id);
        eeprom_update_block(rec, (void *)EE_HEAD_ID_ADDR, HEAD_ID_RECORD);
    }
    head_id_hex(rec, out);
}

#endif
