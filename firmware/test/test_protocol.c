/*
 * Protocol tests: CRC, the examples of docs/protocol.md, parsing of every command and of every
 * kind of bad line, framing, and the encoding of every device message. The expected lines were
 * framed by an independent CRC-16/CCITT-FALSE implementation (the same algorithm as the Rust
 * encoder of common/src/protocol.rs, version 2).
 */
#include "protocol.h"
#include "tinytest.h"

#include <stdint.h>
#include <string.h>

static uint8_t parse(const char *line, proto_cmd *cmd, char *text)
{
    memset(cmd, 0xA5, sizeof *cmd);
    return proto_parse_command(line, (uint8_t)strlen(line), cmd, text);
}

static const char *encode(const dev_msg *m)
{
    static char out[PROTO_OUT_CAP];
    uint8_t n = proto_encode(m, out);
    if (n != strlen(out)) {
        TT_FAIL("length %u vs strlen %zu", n, strlen(out));
    }
    return out;
}

static void crc_check_value(void)
{
    CHECK_INT(proto_crc16("123456789", 9), 0x29B1);
    CHECK_INT(proto_crc16("", 0), 0xFFFF);
    uint16_t crc = 0xFFFF;
    for (const char *p = "123456789"; *p; p++) {
        crc = proto_crc16_update(crc, (uint8_t)*p);
    }
    CHECK_INT(crc, 0x29B1);
}

static void protocol_doc_examples(void)
{
    CHECK_INT(proto_crc16("STOP", 4), 0xAF2E);
    CHECK_INT(proto_crc16("SCAN,FULL", 9), 0x36C7);
    CHECK_INT(proto_crc16("HELLO,2", 7), 0x4975);
    proto_cmd c;
    char text[PROTO_TEXT_MAX + 1];
    CHECK_INT(parse("$STOP*AF2E", &c, text), ERR_NONE);
    CHECK_INT(c.kind, CMD_STOP);
    CHECK_INT(parse("$SCAN,FULL*36C7\n", &c, text), ERR_NONE);
    CHECK_INT(c.kind, CMD_SCAN_FULL);
    CHECK_INT(parse("$HELLO,2*4975\r\n", &c, text), ERR_NONE);
    CHECK_INT(c.kind, CMD_HELLO);
    CHECK_INT(c.version, 2);
}

static void parses_every_command(void)
{
    proto_cmd c;
    char text[PROTO_TEXT_MAX + 1];
    CHECK_INT(parse("$HELLO,1*7916", &c, text), ERR_NONE);
    CHECK_INT(c.kind, CMD_HELLO);
    CHECK_INT(c.version, 1);
    CHECK_INT(parse("$SCAN,LOCAL,-3000,4500*A139", &c, text), ERR_NONE);
    CHECK_INT(c.kind, CMD_SCAN_LOCAL);
    CHECK_INT(c.from_cdeg, -3000);
    CHECK_INT(c.to_cdeg, 4500);
    CHECK_INT(parse("$STATUS*2DAA", &c, text), ERR_NONE);
    CHECK_INT(c.kind, CMD_STATUS);
    CHECK_INT(parse("$RESET*7DB2", &c, text), ERR_NONE); /* the Rust encoder's line */
    CHECK_INT(c.kind, CMD_RESET);
    /* Lower-case CRC digits are accepted. */
    CHECK_INT(parse("$STOP*af2e", &c, text), ERR_NONE);
    CHECK_INT(c.kind, CMD_STOP);
}

/* Frames a body with its CRC, like the Rust encoder. */
static const char *framed(const char *body)
{
    static char line[300];
    snprintf(line, sizeof line, "$%s*%04X", body, proto_crc16(body, strlen(body)));
    return line;
}

static void rejects_bad_crc(void)
{
    proto_cmd c;
    char text[PROTO_TEXT_MAX + 1];
    CHECK_INT(parse("$SCAN,FULM*36C7", &c, text), ERR_CHECKSUM);
    CHECK_STR(text, "check mismatch: line says 36C7, body gives 26E6");
    CHECK_INT(parse("$STOP*AF2F", &c, text), ERR_CHECKSUM);
    /* Two bits flipped in the same position of two bytes: the XOR of version 1 missed this. */
    char line[32];
    strcpy(line, "$SCAN,FULL*36C7");
    line[1] ^= 0x01;
    line[2] ^= 0x01;
    CHECK_INT(parse(line, &c, text), ERR_CHECKSUM);
}

static void rejects_version1_framing_and_bad_frames(void)
{
    proto_cmd c;
    char text[PROTO_TEXT_MAX + 1];
    /* Version 1: two XOR digits ("$STOP*18" is docs/protocol.md's example). */
    CHECK_INT(parse("$STOP*18", &c, text), ERR_SYNTAX);
    CHECK_STR(text, "line check is not 4 hex digits (another protocol version?)");
    CHECK_INT(parse("$STOP*AF2E0", &c, text), ERR_SYNTAX);
    CHECK_INT(parse("$STOP*AG2E", &c, text), ERR_SYNTAX);
    CHECK_INT(parse("STOP*AF2E", &c, text), ERR_SYNTAX);
    CHECK_STR(text, "line does not start with '$'");
    CHECK_INT(parse("x$STOP*AF2E", &c, text), ERR_SYNTAX);
    CHECK_INT(parse("$STOP", &c, text), ERR_SYNTAX);
    CHECK_STR(text, "line has no '*' checksum separator");
    CHECK_INT(parse("", &c, text), ERR_SYNTAX);
    CHECK_INT(parse("$ST\x01OP*AF2E", &c, text), ERR_SYNTAX);
    CHECK_STR(text, "line contains non-printable or non-ASCII bytes");
    CHECK_INT(parse("$ST\xC3OP*AF2E", &c, text), ERR_SYNTAX);
    /* Longer than 160 bytes even with a good CRC. */
    char body[200];
    memset(body, 'A', 170);
    body[170] = '\0';
    CHECK_INT(parse(framed(body), &c, text), ERR_SYNTAX);
    CHECK_STR(text, "line longer than 160 bytes");
}

static void rejects_unknown_and_malformed_commands(void)
{
    proto_cmd c;
    char text[PROTO_TEXT_MAX + 1];
    CHECK_INT(parse(framed("FOO"), &c, text), ERR_SYNTAX);
    CHECK_STR(text, "unknown message tag \"FOO\"");
    CHECK_INT(parse(framed(""), &c, text), ERR_SYNTAX);
    CHECK_INT(parse(framed("stop"), &c, text), ERR_SYNTAX);
    CHECK_INT(parse(framed("STOP,1"), &c, text), ERR_SYNTAX);
    CHECK_STR(text, "wrong number of fields for STOP: expected 1, got 2");
    CHECK_INT(parse(framed("STATUS,"), &c, text), ERR_SYNTAX);
    CHECK_INT(parse(framed("RESET,1"), &c, text), ERR_SYNTAX);
    CHECK_INT(parse(framed("HELLO"), &c, text), ERR_SYNTAX);
    CHECK_INT(parse(framed("HELLO,2,3"), &c, text), ERR_SYNTAX);
    CHECK_INT(parse(framed("HELLO,-2"), &c, text), ERR_SYNTAX);
    CHECK_INT(parse(framed("HELLO,+2"), &c, text), ERR_SYNTAX);
    CHECK_INT(parse(framed("HELLO, 2"), &c, text), ERR_SYNTAX);
    CHECK_INT(parse(framed("HELLO,"), &c, text), ERR_SYNTAX);
    CHECK_INT(parse(framed("HELLO,4294967296"), &c, text), ERR_SYNTAX);
    CHECK_INT(parse(framed("HELLO,4294967295"), &c, text), ERR_NONE);
    CHECK_INT(c.version, 4294967295u);
    CHECK_STR(text, "");
    CHECK_INT(parse(framed("SCAN"), &c, text), ERR_SYNTAX);
    CHECK_STR(text, "field scan kind is malformed");
    CHECK_INT(parse(framed("SCAN,WIDE"), &c, text), ERR_SYNTAX);
    CHECK_INT(parse(framed("SCAN,FULL,1"), &c, text), ERR_SYNTAX);
    CHECK_INT(parse(framed("SCAN,LOCAL,100"), &c, text), ERR_SYNTAX);
    CHECK_INT(parse(framed("SCAN,LOCAL,100,200,300"), &c, text), ERR_SYNTAX);
    CHECK_INT(parse(framed("SCAN,LOCAL,300,100"), &c, text), ERR_SYNTAX);
    CHECK_STR(text, "field local scan segment (from >= to) is malformed");
    CHECK_INT(parse(framed("SCAN,LOCAL,100,100"), &c, text), ERR_SYNTAX);
    CHECK_INT(parse(framed("SCAN,LOCAL,+100,200"), &c, text), ERR_SYNTAX);
    CHECK_INT(parse(framed("SCAN,LOCAL,-,200"), &c, text), ERR_SYNTAX);
    CHECK_INT(parse(framed("SCAN,LOCAL,1e3,2000"), &c, text), ERR_SYNTAX);
    CHECK_INT(parse(framed("SCAN,LOCAL,-2147483649,0"), &c, text), ERR_SYNTAX);
    CHECK_INT(parse(framed("SCAN,LOCAL,-2147483648,2147483647"), &c, text), ERR_NONE);
    CHECK_INT(c.from_cdeg, INT32_MIN);
    CHECK_INT(c.to_cdeg, INT32_MAX);
    /* One spelling per number (docs/protocol.md), as the Rust parser: no leading zeros, no -0. */
    CHECK_INT(parse(framed("SCAN,LOCAL,-0,007"), &c, text), ERR_SYNTAX);
    CHECK_STR(text, "field from angle is malformed");
    CHECK_INT(parse(framed("SCAN,LOCAL,0,007"), &c, text), ERR_SYNTAX);
    CHECK_STR(text, "field to angle is malformed");
    CHECK_INT(parse(framed("SCAN,LOCAL,-0,7"), &c, text), ERR_SYNTAX);
    CHECK_INT(parse(framed("SCAN,LOCAL,-007,7"), &c, text), ERR_SYNTAX);
    CHECK_INT(parse(framed("HELLO,007"), &c, text), ERR_SYNTAX);
    CHECK_STR(text, "field version is malformed");
    CHECK_INT(parse(framed("HELLO,02"), &c, text), ERR_SYNTAX);
    CHECK_INT(parse(framed("HELLO,00"), &c, text), ERR_SYNTAX);
    CHECK_INT(parse(framed("HELLO,0"), &c, text), ERR_NONE);
    CHECK_INT(c.version, 0);
    CHECK_INT(parse(framed("SCAN,LOCAL,0,7"), &c, text), ERR_NONE);
    CHECK_INT(c.from_cdeg, 0);
    CHECK_INT(c.to_cdeg, 7);
    CHECK_INT(parse(framed("SCAN,LOCAL,-10,0"), &c, text), ERR_NONE);
    CHECK_INT(c.from_cdeg, -10);
    CHECK_INT(c.to_cdeg, 0);
}

/* Feeds a string to the framer, collecting lines ("<overflow>" for an overlong one). */
static int feed(proto_framer *f, const char *bytes, size_t n, char out[][PROTO_MAX_LINE + 1], int max)
{
    int got = 0;
    for (size_t i = 0; i < n; i++) {
        uint8_t r = proto_framer_push(f, (uint8_t)bytes[i]);
        if (r == FRAME_LINE && got < max) {
            memcpy(out[got], f->buf, f->line_len);
            out[got][f->line_len] = '\0';
            got++;
        } else if (r == FRAME_OVERFLOW && got < max) {
            strcpy(out[got++], "<overflow>");
        }
    }
    return got;
}

static void framer_splits_lines_and_drops_overlong_ones(void)
{
    proto_framer f;
    proto_framer_init(&f);
    char out[8][PROTO_MAX_LINE + 1];
    const char *a = "$A*0041\r\n\n\r\n$B";
    int n = feed(&f, a, strlen(a), out, 8);
    const char *b = "*0042\n";
    n += feed(&f, b, strlen(b), out + n, 8 - n);
    char junk[200];
    memset(junk, 'x', sizeof junk);
    n += feed(&f, junk, sizeof junk, out + n, 8 - n);
    const char *c = "more junk\n$C*0043\n";
    n += feed(&f, c, strlen(c), out + n, 8 - n);
    CHECK_INT(n, 4);
    CHECK_STR(out[0], "$A*0041");
    CHECK_STR(out[1], "$B*0042");
    CHECK_STR(out[2], "<overflow>");
    CHECK_STR(out[3], "$C*0043");
}

static void framer_line_length_limit_is_160(void)
{
    proto_framer f;
    proto_framer_init(&f);
    char out[4][PROTO_MAX_LINE + 1];
    char line[170];
    memset(line, 'y', 160);
    line[160] = '\n';
    CHECK_INT(feed(&f, line, 161, out, 4), 1);
    CHECK_INT(strlen(out[0]), 160);
    memset(line, 'z', 161);
    line[161] = '\n';
    CHECK_INT(feed(&f, line, 162, out, 4), 1);
    CHECK_STR(out[0], "<overflow>");
    /* Resynchronised: the next line is whole. */
    CHECK_INT(feed(&f, "$STOP*AF2E\n", 11, out, 4), 1);
    CHECK_STR(out[0], "$STOP*AF2E");
}

static void encodes_hello(void)
{
    dev_msg m;
    m.kind = MSG_HELLO;
    m.u.hello.firmware_P = "sonar-head 0.2.0";
    m.u.hello.head_id = "3F2A9C0417B6E5D1";
    m.u.hello.step_cdeg = 150;
    m.u.hello.pings = 4;
    m.u.hello.min_cdeg = -15000;
    m.u.hello.max_cdeg = 15000;
    CHECK_STR(encode(&m), "$HELLO,2,sonar-head 0.2.0,3F2A9C0417B6E5D1,150,4,-15000,15000*CAAA\n");
}

static void encodes_ack_lim_swp(void)
{
    dev_msg m;
    m.kind = MSG_ACK;
    m.u.ack.tag_P = "SCAN";
    CHECK_STR(encode(&m), "$ACK,SCAN*9293\n");
    m.u.ack.tag_P = "STOP";
    CHECK_STR(encode(&m), "$ACK,STOP*8490\n");
    m.kind = MSG_LIM;
    m.u.lim.which = LIMIT_MIN;
    CHECK_STR(encode(&m), "$LIM,MIN*5577\n");
    m.u.lim.which = LIMIT_MAX;
    CHECK_STR(encode(&m), "$LIM,MAX*AE29\n");
    m.kind = MSG_SWP_START;
    m.u.swp.sweep = 2;
    m.u.swp.dir = 1;
    m.u.swp.full = false;
    m.u.swp.from_cdeg = -3000;
    m.u.swp.to_cdeg = 3000;
    CHECK_STR(encode(&m), "$SWP,START,2,+,L,-3000,3000*03E4\n");
    m.u.swp.sweep = 1;
    m.u.swp.full = true;
    m.u.swp.from_cdeg = -14700;
    m.u.swp.to_cdeg = 14700;
    CHECK_STR(encode(&m), "$SWP,START,1,+,F,-14700,14700*256E\n");
    m.kind = MSG_SWP_END;
    m.u.swp.sweep = 2;
    CHECK_STR(encode(&m), "$SWP,END,2*8B1F\n");
}

static void encodes_reading_like_the_rust_encoder(void)
{
    static const uint16_t echo[4] = {5800, 5830, 0, 5790};
    dev_msg m;
    m.kind = MSG_RD;
    m.u.rd.seq = 7;
    m.u.rd.time_ms = 123456;
    m.u.rd.sweep = 3;
    m.u.rd.dir = -1;
    m.u.rd.angle_cdeg = -14700;
    m.u.rd.n = 4;
    m.u.rd.echo_us = echo;
    CHECK_STR(encode(&m), "$RD,7,123456,3,-,-14700,4,5800,5830,0,5790*2427\n");
    /* The longest reading line fits the 160-byte limit. */
    static const uint16_t big[8] = {65535, 65535, 65535, 65535, 65535, 65535, 65535, 65535};
    m.u.rd.seq = m.u.rd.time_ms = m.u.rd.sweep = UINT32_MAX;
    m.u.rd.angle_cdeg = INT32_MIN;
    m.u.rd.n = 8;
    m.u.rd.echo_us = big;
    CHECK(strlen(encode(&m)) - 1 <= PROTO_MAX_LINE);
}

static void encodes_status(void)
{
    dev_msg m;
    m.kind = MSG_ST;
    m.u.st.state = STATE_FULL;
    m.u.st.angle_cdeg = 4425;
    m.u.st.dir = -1;
    m.u.st.sweep = 9;
    CHECK_STR(encode(&m), "$ST,FULL,4425,-,9*5A5E\n");
    m.u.st.state = STATE_HOMING;
    m.u.st.angle_cdeg = -15000;
    m.u.st.sweep = 0;
    CHECK_STR(encode(&m), "$ST,HOMING,-15000,-,0*FB13\n");
    m.u.st.state = STATE_IDLE;
    m.u.st.dir = 1;
    CHECK_STR(encode(&m), "$ST,IDLE,-15000,+,0*B4A1\n");
    m.u.st.state = STATE_LOCAL;
    m.u.st.angle_cdeg = 0;
    m.u.st.sweep = UINT32_MAX;
    CHECK_STR(encode(&m), "$ST,LOCAL,0,+,4294967295*AD3D\n");
    m.u.st.state = STATE_FAULT;
    m.u.st.sweep = 3;
    CHECK_STR(encode(&m), "$ST,FAULT,0,+,3*9EC2\n");
}

static void encodes_errors_with_sanitised_text(void)
{
    dev_msg m;
    proto_err_P(&m, ERR_RANGE, "angle outside limits");
    CHECK_STR(encode(&m), "$ERR,RANGE,angle outside limits*F2F6\n");
    proto_err_P(&m, ERR_HARDWARE, "a,b*c$d\x01 e");
    CHECK_STR(encode(&m), "$ERR,HARDWARE,a_b_c_d_ e*3F2F\n");
    /* Every code has its name. */
    const char *names[] = {"CHECKSUM", "SYNTAX", "RANGE", "VERSION", "HARDWARE"};
    for (uint8_t code = ERR_CHECKSUM; code <= ERR_HARDWARE; code++) {
        proto_err_P(&m, code, "x");
        char expect[40];
        snprintf(expect, sizeof expect, "$ERR,%s,x*", names[code - ERR_CHECKSUM]);
        CHECK(strncmp(encode(&m), expect, strlen(expect)) == 0);
    }
    /* Text is cut at 80 characters. */
    char long_text[120];
    memset(long_text, 'q', sizeof long_text - 1);
    long_text[sizeof long_text - 1] = '\0';
    m.kind = MSG_ERR;
    m.u.err.code = ERR_SYNTAX;
    memcpy(m.u.err.text, long_text, PROTO_TEXT_MAX);
    m.u.err.text[PROTO_TEXT_MAX] = '\0';
    CHECK_INT(strlen(encode(&m)), strlen("$ERR,SYNTAX,*XXXX\n") + PROTO_TEXT_MAX);
}

static void encoded_lines_parse_back_through_the_crc(void)
{
    /* A line the device encodes carries a CRC the command parser accepts (the same framing). */
    dev_msg m;
    proto_err_P(&m, ERR_SYNTAX, "x");
    const char *line = encode(&m);
    proto_cmd c;
    char text[PROTO_TEXT_MAX + 1];
    CHECK_INT(parse(line, &c, text), ERR_SYNTAX); /* unknown tag ERR, but past the CRC */
    CHECK(strstr(text, "unknown message tag") != NULL);
}

static void number_formatting(void)
{
    char buf[40];
    tbuf t;
    tb_init(&t, buf, sizeof buf - 1);
    tb_i32(&t, INT32_MIN);
    tb_char(&t, ' ');
    tb_i32(&t, 0);
    tb_char(&t, ' ');
    tb_u32(&t, UINT32_MAX);
    tb_char(&t, ' ');
    tb_hex16(&t, 0x0A0F);
    CHECK_STR(buf, "-2147483648 0 4294967295 0A0F");
    tb_init(&t, buf, 5);
    tb_u32(&t, 1234567);
    CHECK_STR(buf, "12345");
}

void protocol_tests(void)
{
    RUN(crc_check_value);
    RUN(protocol_doc_examples);
    RUN(parses_every_command);
    RUN(rejects_bad_crc);
    RUN(rejects_version1_framing_and_bad_frames);
    RUN(rejects_unknown_and_malformed_commands);
    RUN(framer_splits_lines_and_drops_overlong_ones);
    RUN(framer_line_length_limit_is_160);
    RUN(encodes_hello);
    RUN(encodes_ack_lim_swp);
    RUN(encodes_reading_like_the_rust_encoder);
    RUN(encodes_status);
    RUN(encodes_errors_with_sanitised_text);
    RUN(encoded_lines_parse_back_through_the_crc);
    RUN(number_formatting);
}
