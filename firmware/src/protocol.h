/*
 * protocol.h — the wire protocol, version 2 (docs/protocol.md), pure and host-testable:
 * CRC-16/CCITT-FALSE, line framing, command parsing and device message encoding.
 *
 * Every line is `$BODY*HHHH\n`: HHHH is the CRC-16/CCITT-FALSE of BODY (poly 0x1021, init 0xFFFF,
 * no reflection, no final XOR), four upper-case hex digits; lower-case is accepted on input.
 * This mirrors common/src/protocol.rs (parse_command, encode_device, LineFramer).
 */
#ifndef SONAR_PROTOCOL_H
#define SONAR_PROTOCOL_H

#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

#define PROTO_VERSION 2u
/* Longest line either side accepts (terminator excluded); longer input is discarded whole. */
#define PROTO_MAX_LINE 160u
#define PROTO_MAX_PINGS 8u
/* Free text fields (firmware name, ERR text) are cut to this many characters. */
#define PROTO_TEXT_MAX 80u
/* Room for one encoded line: '$', body, "*HHHH\n", NUL. */
#define PROTO_OUT_CAP (PROTO_MAX_LINE + 8u)

/* ---- CRC ------------------------------------------------------------------------------------- */

uint16_t proto_crc16_update(uint16_t crc, uint8_t byte);
uint16_t proto_crc16(const void *data, size_t len);

/* ---- text building (bounded, always NUL-terminated) ------------------------------------------ */

typedef struct {
    char *buf;
    uint8_t len;
    uint8_t cap; /* characters, NUL excluded */
} tbuf;

void tb_init(tbuf *t, char *buf, uint8_t cap);
void tb_char(tbuf *t, char c);
void tb_mem(tbuf *t, const char *s, uint8_t n);
/* A NUL-terminated string in flash (FSTR / PROGMEM) on the AVR; a plain string on the host. */
void tb_str_P(tbuf *t, const char *s_P);
void tb_u32(tbuf *t, uint32_t v);
void tb_i32(tbuf *t, int32_t v);
void tb_hex16(tbuf *t, uint16_t v);

/* ---- line framing (common/src/protocol.rs LineFramer, Terminators::Newline) ------------------ */

typedef struct {
    char buf[PROTO_MAX_LINE];
    uint8_t len;      /* bytes of the line being assembled */
    uint8_t line_len; /* after FRAME_LINE: length of the complete line in buf */
    bool overflowed;
} proto_framer;

enum { FRAME_NONE = 0, FRAME_LINE, FRAME_OVERFLOW };

void proto_framer_init(proto_framer *f);
/* Feeds one byte. FRAME_LINE: f->buf[0..f->line_len) holds a complete non-empty line without its
 * trailing "\r\n" (valid until the next push). FRAME_OVERFLOW: a line grew past PROTO_MAX_LINE;
 * it is being discarded up to the next '\n' (reported once). */
uint8_t proto_framer_push(proto_framer *f, uint8_t byte);

/* ---- commands (PC -> device) ----------------------------------------------------------------- */

typedef enum {
    CMD_HELLO = 0,
    CMD_SCAN_FULL,
    CMD_SCAN_LOCAL,
    CMD_STOP,
    CMD_STATUS,
    CMD_RESET,
} cmd_kind;

typedef struct {
    uint8_t kind; /* cmd_kind */
    uint32_t version;
    int32_t from_cdeg;
    int32_t to_cdeg;
} proto_cmd;

typedef enum {
    ERR_NONE = 0,
    ERR_CHECKSUM,
    ERR_SYNTAX,
    ERR_RANGE,
    ERR_VERSION,
    ERR_HARDWARE,
} err_code;

/* Parses one line (terminator optional). Returns ERR_NONE and fills *cmd, or ERR_CHECKSUM /
 * ERR_SYNTAX and writes why into text (PROTO_TEXT_MAX + 1 bytes). The CRC is checked before any
 * field is looked at; a version-1 line (two checksum digits) is ERR_SYNTAX. */
uint8_t proto_parse_command(const char *line, uint8_t len, proto_cmd *cmd, char *text);

/* ---- device messages (device -> PC) ---------------------------------------------------------- */

typedef enum {
    MSG_HELLO = 0,
    MSG_ACK,
    MSG_RD,
    MSG_LIM,
    MSG_SWP_START,
    MSG_SWP_END,
    MSG_ST,
    MSG_ERR,
} msg_kind;

enum { LIMIT_MIN = 0, LIMIT_MAX = 1 };
enum { STATE_IDLE = 0, STATE_FULL, STATE_LOCAL, STATE_HOMING, STATE_FAULT };

typedef struct {
    uint8_t kind; /* msg_kind */
    union {
        struct {
            const char *firmware_P; /* flash */
            const char *head_id;    /* RAM */
            uint16_t step_cdeg;
            uint8_t pings;
            int32_t min_cdeg, max_cdeg;
        } hello;
        struct {
            const char *tag_P; /* flash */
        } ack;
        struct {
            uint32_t seq, time_ms, sweep;
            int8_t dir; /* +1 CCW '+', -1 CW '-' */
            int32_t angle_cdeg;
            uint8_t n;
            const uint16_t *echo_us;
        } rd;
        struct {
            uint8_t which; /* LIMIT_MIN / LIMIT_MAX */
        } lim;
        struct {
            uint32_t sweep;
            int8_t dir;
            bool full;
            int32_t from_cdeg, to_cdeg;
        } swp;
        struct {
            uint8_t state; /* STATE_* */
            int32_t angle_cdeg;
            int8_t dir;
            uint32_t sweep;
        } st;
        struct {
            uint8_t code; /* err_code */
            char text[PROTO_TEXT_MAX + 1];
        } err;
    } u;
} dev_msg;

/* Encodes a whole line "$BODY*HHHH\n" into out (PROTO_OUT_CAP bytes, NUL-terminated); returns its
 * length. Free text is sanitised like the Rust encoder: '$', '*', ',' and non-printables become
 * '_', at most PROTO_TEXT_MAX characters. */
uint8_t proto_encode(const dev_msg *m, char *out);

/* Sets up an ERR message whose text is a flash string. */
void proto_err_P(dev_msg *m, uint8_t code, const char *text_P);
/* ERR,VERSION for a HELLO of another version. */
void proto_version_err(dev_msg *m, uint32_t host_version);
/* ERR,RANGE for a SCAN,LOCAL: no reading centre in from..to (no_centre), or a segment outside the
 * head's limits min..max. */
void proto_range_err(dev_msg *m, bool no_centre, int32_t from_cdeg, int32_t to_cdeg, int32_t min_cdeg,
                     int32_t max_cdeg);

#endif
