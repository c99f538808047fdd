/*
 * head_id.h — the head's identity: 8 random bytes in EEPROM (bytes 0..7) with their
 * CRC-16/CCITT-FALSE (bytes 8..9, big-endian), made at the first boot from the jitter of the
 * watchdog oscillator against Timer1, sent as 16 upper-case hex digits.
 */
#ifndef SONAR_HEAD_ID_H
#define SONAR_HEAD_ID_H

#include "config.h"

#include <stdbool.h>
#include <stdint.h>

#define HEAD_ID_RECORD (HEAD_ID_BYTES + 2)
#define HEAD_ID_HEX_LEN (2 * HEAD_ID_BYTES)

/* ---- pure (host-tested) ---------------------------------------------------------------------- */

/* Whether an EEPROM record (id + big-endian CRC) is intact. A blank chip (all 0xFF) is not. */
bool head_id_record_valid(const uint8_t rec[HEAD_ID_RECORD]);
/* Builds the record for an id. */
void head_id_make_record(uint8_t rec[HEAD_ID_RECORD], const uint8_t id[HEAD_ID_BYTES]);
/* 16 upper-case hex digits and a NUL. */
void head_id_hex(const uint8_t id[HEAD_ID_BYTES], char out[HEAD_ID_HEX_LEN + 1]);

/* Entropy pool: timer samples in, 8 well-mixed bytes out. */
typedef struct {
    uint32_t h[2];
    uint8_t n;
} head_id_pool;
void head_id_pool_init(head_id_pool *p);
void head_id_pool_add(head_id_pool *p, uint16_t sample);
void head_id_pool_finish(head_id_pool *p, uint8_t id[HEAD_ID_BYTES]);

/* ---- AVR ------------------------------------------------------------------------------------- */

/* Reads the id from EEPROM, or makes and stores one (≈ 1 s, once); writes the hex form. Uses the
 * watchdog in interrupt mode and Timer1 at full speed, and leaves both off: call it before
 * sonar_init and before the watchdog is armed. */
void head_id_load(char out[HEAD_ID_HEX_LEN + 1]);

#endif
