/*
 * protocol.c — see protocol.h. No I/O, no globals: the host unit tests run this very file.
 */
#include "protocol.h"

#include "compat.h"

#include <string.h>

/* ---- CRC-16/CCITT-FALSE (docs/protocol.md: poly 0x1021, init 0xFFFF, no reflection, no xorout;
 * check value of "123456789" = 0x29B1). Bitwise: 8 shifts per byte, no 512-byte table. -------- */

uint16_t proto_crc16_update(uint16_t crc, uint8_t byte)
{
    crc ^= (uint16_t)((uint16_t)byte << 8);
    for (uint8_t i = 0; i < 8; i++) {
        if (crc & 0x8000u) {
            crc = (uint16_t)((crc << 1) ^ 0x1021u);
        } else {
            crc = (uint16_t)(crc << 1);
        }
    }
    return crc;
}

uint16_t proto_crc16(const void *data, size_t len)
{
    const uint8_t *p = (const uint8_t *)data;
    uint16_t crc = 0xFFFFu;
    while (len--) {
        crc = proto_crc16_update(crc, *p++);
    }
    return crc;
}

/* ---- text building --------------------------------------------------------------------------- */

void tb_init(tbuf *t, char *buf, uint8_t cap)
{
    t->buf = buf;
    t->len = 0;
    t->cap = cap;
    buf[0] = '\0';
}

void tb_char(tbuf *t, char c)
{
    if (t->len < t->cap) {
        t->buf[t->len++] = c;
        t->buf[t->len] = '\0';
    }
}

void tb_mem(tbuf *t, const char *s, uint8_t n)
{
    for (uint8_t i = 0; i < n; i++) {
        tb_char(t, s[i]);
    }
}

void tb_str_P(tbuf *t, const char *s_P)
{
    for (;;) {
        char c = flash_char(s_P++);
        if (c == '\0') {
            return;
        }
        tb_char(t, c);
    }
}

void tb_u32(tbuf *t, uint32_t v)
{
    char digits[10];
    uint8_t n = 0;
    do {
        digits[n++] = (char)('0' + (uint8_t)(v % 10u));
        v /= 10u;
    } while (v != 0);
    while (n) {
        tb_char(t, digits[--n]);
    }
}

void tb_i32(tbuf *t, int32_t v)
{
    if (v < 0) {
        tb_char(t, '-');
        tb_u32(t, (uint32_t)0 - (uint32_t)v); /* also right for INT32_MIN */
    } else {
        tb_u32(t, (uint32_t)v);
    }
}

static char hex_digit(uint8_t v)
{
    return (char)(v < 10 ? '0' + v : 'A' + (v - 10));
}

void tb_hex16(tbuf *t, uint16_t v)
{
    for (int8_t shift = 12; shift >= 0; shift -= 4) {
        tb_char(t, hex_digit((uint8_t)((v >> shift) & 0xFu)));
    }
}

/* Rust sanitize_text: graphic ASCII except '$', '*', ',' (and the space) pass; the rest is '_'. */
static char sanitized(char c)
{
    if (c == ' ' || (c > ' ' && c < 0x7F && c != '$' && c != '*' && c != ',')) {
        return c;
    }
    return '_';
}

static void tb_text(tbuf *t, const char *s, bool flash)
{
    for (uint8_t n = 0; n < PROTO_TEXT_MAX; n++) {
        char c = flash ? flash_char(s + n) : s[n];
        if (c == '\0') {
            return;
        }
        tb_char(t, sanitized(c));
    }
}

/* ---- line framing ---------------------------------------------------------------------------- */

void proto_framer_init(proto_framer *f)
{
    f->len = 0;
    f->line_len = 0;
    f->overflowed = false;
}

static uint8_t trimmed_len(const char *s, uint8_t len)
{
    while (len > 0 && (s[len - 1] == '\n' || s[len - 1] == '\r')) {
        len--;
    }
    return len;
}

uint8_t proto_framer_push(proto_framer *f, uint8_t byte)
{
    if (byte == '\n') {
        uint8_t len = f->len;
        bool overflowed = f->overflowed;
        f->len = 0;
        f->overflowed = false;
        if (overflowed) {
            return FRAME_NONE;
        }
        len = trimmed_len(f->buf, len);
        if (len == 0) {
            return FRAME_NONE; /* empty lines (and lone "\r") are ignored */
        }
        f->line_len = len; /* the caller reads buf[0..line_len) before the next push */
        return FRAME_LINE;
    }
    if (f->overflowed) {
        return FRAME_NONE; /* skip the rest of an overlong line */
    }
    if (f->len >= PROTO_MAX_LINE) {
        f->len = 0;
        f->overflowed = true;
        return FRAME_OVERFLOW;
    }
    f->buf[f->len++] = (char)byte;
    return FRAME_NONE;
}

/* ---- command parsing ------------------------------------------------------------------------- */

typedef struct {
    const char *s;
    uint8_t n;
} field;

#define MAX_FIELDS 5 /* SCAN,LOCAL,a,b has 4; one more detects "too many" */

static bool field_is_P(field f, const char *s_P)
{
    for (uint8_t i = 0; i < f.n; i++) {
        char c = flash_char(s_P + i);
        if (c == '\0' || c != f.s[i]) {
            return false;
        }
    }
    return flash_char(s_P + f.n) == '\0';
}

static int8_t hex_value(char c)
{
    if (c >= '0' && c <= '9') {
        return (int8_t)(c - '0');
    }
    if (c >= 'A' && c <= 'F') {
        return (int8_t)(c - 'A' + 10);
    }
    if (c >= 'a' && c <= 'f') {
        return (int8_t)(c - 'a' + 10);
    }
    return -1;
}

/* Rust `num`: no empty field, no '+' sign, no spaces, no overflow; '-' only for signed types. */
/* docs/protocol.md: one spelling per number, so no leading zeros ("007") and, in parse_i32, no
 * "-0": a line that is taken reads back as itself, as in the Rust parser. */
static bool parse_u32(field f, uint32_t *out)
{
    if (f.n == 0 || (f.n > 1 && f.s[0] == '0')) {
        return false;
    }
    uint32_t v = 0;
    for (uint8_t i = 0; i < f.n; i++) {
        char c = f.s[i];
        if (c < '0' || c > '9') {
            return false;
        }
        uint8_t d = (uint8_t)(c - '0');
        if (v > (UINT32_MAX - d) / 10u) {
            return false;
        }
        v = v * 10u + d;
    }
    *out = v;
    return true;
}

static bool parse_i32(field f, int32_t *out)
{
    bool neg = f.n > 0 && f.s[0] == '-';
    field digits = {f.s + (neg ? 1 : 0), (uint8_t)(f.n - (neg ? 1 : 0))};
    uint32_t mag;
    if (!parse_u32(digits, &mag)) {
        return false;
    }
    if (neg) {
        if (mag == 0 || mag > 2147483648UL) {
            return false;
        }
        *out = (int32_t)(0 - mag);
    } else {
        if (mag > 2147483647UL) {
            return false;
        }
        *out = (int32_t)mag;
    }
    return true;
}

static uint8_t syntax_P(char *text, const char *why_P)
{
    tbuf t;
    tb_init(&t, text, PROTO_TEXT_MAX);
    tb_str_P(&t, why_P);
    return ERR_SYNTAX;
}

static uint8_t field_count(char *text, const char *tag_P, uint8_t expected, uint8_t got)
{
    tbuf t;
    tb_init(&t, text, PROTO_TEXT_MAX);
    tb_str_P(&t, FSTR("wrong number of fields for "));
    tb_str_P(&t, tag_P);
    tb_str_P(&t, FSTR(": expected "));
    tb_u32(&t, expected);
    tb_str_P(&t, FSTR(", got "));
    tb_u32(&t, got);
    return ERR_SYNTAX;
}

static uint8_t bad_field(char *text, const char *what_P)
{
    tbuf t;
    tb_init(&t, text, PROTO_TEXT_MAX);
    tb_str_P(&t, FSTR("field "));
    tb_str_P(&t, what_P);
    tb_str_P(&t, FSTR(" is malformed"));
    return ERR_SYNTAX;
}

uint8_t proto_parse_command(const char *line, uint8_t len, proto_cmd *cmd, char *text)
{
    text[0] = '\0';
    len = trimmed_len(line, len);
    if (len > PROTO_MAX_LINE) {
        return syntax_P(text, FSTR("line longer than 160 bytes"));
    }
    if (len == 0 || line[0] != '$') {
        return syntax_P(text, FSTR("line does not start with '$'"));
    }
    const char *rest = line + 1;
    uint8_t rest_len = (uint8_t)(len - 1);
    int16_t star = -1;
    for (int16_t i = (int16_t)rest_len - 1; i >= 0; i--) {
        if (rest[i] == '*') {
            star = i;
            break;
        }
    }
    if (star < 0) {
        return syntax_P(text, FSTR("line has no '*' checksum separator"));
    }
    const char *body = rest;
    uint8_t body_len = (uint8_t)star;
    for (uint8_t i = 0; i < body_len; i++) {
        if ((uint8_t)body[i] < 0x20u || (uint8_t)body[i] > 0x7Eu) {
            return syntax_P(text, FSTR("line contains non-printable or non-ASCII bytes"));
        }
    }
    const char *tail = rest + star + 1;
    uint8_t tail_len = (uint8_t)(rest_len - star - 1);
    if (tail_len != 4) {
        /* Also a version-1 line, whose checksum is two XOR digits. */
        return syntax_P(text, FSTR("line check is not 4 hex digits (another protocol version?)"));
    }
    uint16_t declared = 0;
    for (uint8_t i = 0; i < 4; i++) {
        int8_t d = hex_value(tail[i]);
        if (d < 0) {
            return syntax_P(text, FSTR("line check is not 4 hex digits (another protocol version?)"));
        }
        declared = (uint16_t)((declared << 4) | (uint8_t)d);
    }
    uint16_t computed = proto_crc16(body, body_len);
    if (declared != computed) {
        tbuf t;
        tb_init(&t, text, PROTO_TEXT_MAX);
        tb_str_P(&t, FSTR("check mismatch: line says "));
        tb_hex16(&t, declared);
        tb_str_P(&t, FSTR(", body gives "));
        tb_hex16(&t, computed);
        return ERR_CHECKSUM;
    }

    field f[MAX_FIELDS];
    uint8_t nf = 0;
    uint8_t start = 0;
    for (uint8_t i = 0; i <= body_len; i++) {
        if (i == body_len || body[i] == ',') {
            if (nf < MAX_FIELDS) {
                f[nf].s = body + start;
                f[nf].n = (uint8_t)(i - start);
            }
            if (nf < 255) {
                nf++;
            }
            start = (uint8_t)(i + 1);
        }
    }

    if (field_is_P(f[0], FSTR("HELLO"))) {
        if (nf != 2) {
            return field_count(text, FSTR("HELLO"), 2, nf);
        }
        if (!parse_u32(f[1], &cmd->version)) {
            return bad_field(text, FSTR("version"));
        }
        cmd->kind = CMD_HELLO;
        return ERR_NONE;
    }
    if (field_is_P(f[0], FSTR("SCAN"))) {
        if (nf >= 2 && field_is_P(f[1], FSTR("FULL"))) {
            if (nf != 2) {
                return field_count(text, FSTR("SCAN_FULL"), 2, nf);
            }
            cmd->kind = CMD_SCAN_FULL;
            return ERR_NONE;
        }
        if (nf >= 2 && field_is_P(f[1], FSTR("LOCAL"))) {
            if (nf != 4) {
                return field_count(text, FSTR("SCAN_LOCAL"), 4, nf);
            }
            if (!parse_i32(f[2], &cmd->from_cdeg)) {
                return bad_field(text, FSTR("from angle"));
            }
            if (!parse_i32(f[3], &cmd->to_cdeg)) {
                return bad_field(text, FSTR("to angle"));
            }
            if (cmd->from_cdeg >= cmd->to_cdeg) {
                return bad_field(text, FSTR("local scan segment (from >= to)"));
            }
            cmd->kind = CMD_SCAN_LOCAL;
            return ERR_NONE;
        }
        return bad_field(text, FSTR("scan kind"));
    }
    if (field_is_P(f[0], FSTR("STOP"))) {
        if (nf != 1) {
            return field_count(text, FSTR("STOP"), 1, nf);
        }
        cmd->kind = CMD_STOP;
        return ERR_NONE;
    }
    if (field_is_P(f[0], FSTR("STATUS"))) {
        if (nf != 1) {
            return field_count(text, FSTR("STATUS"), 1, nf);
        }
        cmd->kind = CMD_STATUS;
        return ERR_NONE;
    }
    if (field_is_P(f[0], FSTR("RESET"))) {
        if (nf != 1) {
            return field_count(text, FSTR("RESET"), 1, nf);
        }
        cmd->kind = CMD_RESET;
        return ERR_NONE;
    }
    tbuf t;
    tb_init(&t, text, PROTO_TEXT_MAX);
    tb_str_P(&t, FSTR("unknown message tag \""));
    tb_mem(&t, f[0].s, f[0].n);
    tb_char(&t, '"');
    return ERR_SYNTAX;
}

/* ---- device message encoding ----------------------------------------------------------------- */

static const char ERR_NAMES[] PROGMEM = "CHECKSUM\0SYNTAX\0RANGE\0VERSION\0HARDWARE\0";
static const char STATE_NAMES[] PROGMEM = "IDLE\0FULL\0LOCAL\0HOMING\0FAULT\0";

/* The n-th NUL-separated name of a flash table. */
static void tb_nth_P(tbuf *t, const char *table_P, uint8_t n)
{
    while (n--) {
        while (flash_char(table_P++) != '\0') {
        }
    }
    tb_str_P(t, table_P);
}

static char dir_char(int8_t dir)
{
    return dir > 0 ? '+' : '-';
}

uint8_t proto_encode(const dev_msg *m, char *out)
{
    tbuf t;
    tb_init(&t, out, PROTO_OUT_CAP - 1);
    tb_char(&t, '$');
    switch (m->kind) {
    case MSG_HELLO:
        tb_str_P(&t, FSTR("HELLO,"));
        tb_u32(&t, PROTO_VERSION);
        tb_char(&t, ',');
        tb_text(&t, m->u.hello.firmware_P, true);
        tb_char(&t, ',');
        tb_text(&t, m->u.hello.head_id, false);
        tb_char(&t, ',');
        tb_u32(&t, m->u.hello.step_cdeg);
        tb_char(&t, ',');
        tb_u32(&t, m->u.hello.pings);
        tb_char(&t, ',');
        tb_i32(&t, m->u.hello.min_cdeg);
        tb_char(&t, ',');
        tb_i32(&t, m->u.hello.max_cdeg);
        break;
    case MSG_ACK:
        tb_str_P(&t, FSTR("ACK,"));
        tb_text(&t, m->u.ack.tag_P, true);
        break;
    case MSG_RD:
        tb_str_P(&t, FSTR("RD,"));
        tb_u32(&t, m->u.rd.seq);
        tb_char(&t, ',');
        tb_u32(&t, m->u.rd.time_ms);
        tb_char(&t, ',');
        tb_u32(&t, m->u.rd.sweep);
        tb_char(&t, ',');
        tb_char(&t, dir_char(m->u.rd.dir));
        tb_char(&t, ',');
        tb_i32(&t, m->u.rd.angle_cdeg);
        tb_char(&t, ',');
        tb_u32(&t, m->u.rd.n);
        for (uint8_t i = 0; i < m->u.rd.n && i < PROTO_MAX_PINGS; i++) {
            tb_char(&t, ',');
            tb_u32(&t, m->u.rd.echo_us[i]);
        }
        break;
    case MSG_LIM:
        tb_str_P(&t, m->u.lim.which == LIMIT_MIN ? FSTR("LIM,MIN") : FSTR("LIM,MAX"));
        break;
    case MSG_SWP_START:
        tb_str_P(&t, FSTR("SWP,START,"));
        tb_u32(&t, m->u.swp.sweep);
        tb_char(&t, ',');
        tb_char(&t, dir_char(m->u.swp.dir));
        tb_char(&t, ',');
        tb_char(&t, m->u.swp.full ? 'F' : 'L');
        tb_char(&t, ',');
        tb_i32(&t, m->u.swp.from_cdeg);
        tb_char(&t, ',');
        tb_i32(&t, m->u.swp.to_cdeg);
        break;
    case MSG_SWP_END:
        tb_str_P(&t, FSTR("SWP,END,"));
        tb_u32(&t, m->u.swp.sweep);
        break;
    case MSG_ST:
        tb_str_P(&t, FSTR("ST,"));
        tb_nth_P(&t, STATE_NAMES, m->u.st.state <= STATE_FAULT ? m->u.st.state : STATE_IDLE);
        tb_char(&t, ',');
        tb_i32(&t, m->u.st.angle_cdeg);
        tb_char(&t, ',');
        tb_char(&t, dir_char(m->u.st.dir));
        tb_char(&t, ',');
        tb_u32(&t, m->u.st.sweep);
        break;
    case MSG_ERR:
    default:
        tb_str_P(&t, FSTR("ERR,"));
        tb_nth_P(&t, ERR_NAMES,
                 (m->u.err.code >= ERR_CHECKSUM && m->u.err.code <= ERR_HARDWARE)
                     ? (uint8_t)(m->u.err.code - ERR_CHECKSUM)
                     : (uint8_t)(ERR_HARDWARE - ERR_CHECKSUM));
        tb_char(&t, ',');
        tb_text(&t, m->u.err.text, false);
        break;
    }
    uint16_t crc = proto_crc16(out + 1, (size_t)(t.len - 1));
    tb_char(&t, '*');
    tb_hex16(&t, crc);
    tb_char(&t, '\n');
    return t.len;
}

void proto_err_P(dev_msg *m, uint8_t code, const char *text_P)
{
    tbuf t;
    m->kind = MSG_ERR;
    m->u.err.code = code;
    tb_init(&t, m->u.err.text, PROTO_TEXT_MAX);
    tb_str_P(&t, text_P);
}

void proto_version_err(dev_msg *m, uint32_t host_version)
{
    tbuf t;
    m->kind = MSG_ERR;
    m->u.err.code = ERR_VERSION;
    tb_init(&t, m->u.err.text, PROTO_TEXT_MAX);
    tb_str_P(&t, FSTR("host speaks version "));
    tb_u32(&t, host_version);
    tb_str_P(&t, FSTR("; device speaks "));
    tb_u32(&t, PROTO_VERSION);
}

void proto_range_err(dev_msg *m, bool no_centre, int32_t from_cdeg, int32_t to_cdeg, int32_t min_cdeg,
                     int32_t max_cdeg)
{
    tbuf t;
    m->kind = MSG_ERR;
    m->u.err.code = ERR_RANGE;
    tb_init(&t, m->u.err.text, PROTO_TEXT_MAX);
    if (no_centre) {
        tb_str_P(&t, FSTR("no reading centre in "));
        tb_i32(&t, from_cdeg);
        tb_str_P(&t, FSTR(".."));
        tb_i32(&t, to_cdeg);
    } else {
        tb_str_P(&t, FSTR("segment outside the limits "));
        tb_i32(&t, min_cdeg);
        tb_str_P(&t, FSTR(".."));
        tb_i32(&t, max_cdeg);
    }
}
