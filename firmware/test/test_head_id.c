/* Head id: the EEPROM record (id + big-endian CRC), the hex form, and the entropy pool. */
#include "head_id.h"
#include "protocol.h"
#include "tinytest.h"

static void record_round_trip_and_blank_chip(void)
{
    const uint8_t id[8] = {0x3F, 0x2A, 0x9C, 0x04, 0x17, 0xB6, 0xE5, 0xD1};
    uint8_t rec[HEAD_ID_RECORD];
    head_id_make_record(rec, id);
    CHECK(head_id_record_valid(rec));
    uint16_t crc = proto_crc16(id, 8);
    CHECK_INT(rec[8], crc >> 8);
    CHECK_INT(rec[9], crc & 0xFF);
    rec[3] ^= 0x10;
    CHECK(!head_id_record_valid(rec));
    uint8_t blank[HEAD_ID_RECORD];
    memset(blank, 0xFF, sizeof blank);
    CHECK(!head_id_record_valid(blank));
    char hex[HEAD_ID_HEX_LEN + 1];
    head_id_hex(id, hex);
    CHECK_STR(hex, "3F2A9C0417B6E5D1");
}

static void entropy_pool_spreads_single_bit_changes(void)
{
    /* One jittering low bit in one of 64 samples changes about half of the 64 output bits. */
    uint8_t a[8], b[8];
    head_id_pool p;
    head_id_pool_init(&p);
    for (int i = 0; i < 64; i++) {
        head_id_pool_add(&p, (uint16_t)(1000 + i * 37));
    }
    head_id_pool_finish(&p, a);
    head_id_pool_init(&p);
    for (int i = 0; i < 64; i++) {
        head_id_pool_add(&p, (uint16_t)(1000 + i * 37 + (i == 40)));
    }
    head_id_pool_finish(&p, b);
    int diff = 0;
    for (int i = 0; i < 8; i++) {
        diff += __builtin_popcount((unsigned)(a[i] ^ b[i]));
    }
    CHECK(diff > 16 && diff < 48);
}

void head_id_tests(void)
{
    RUN(record_round_trip_and_blank_chip);
    RUN(entropy_pool_spreads_single_bit_changes);
}
