/*
 * The servo head's pure parts (servo.c, make HEAD=servo): the angle → pulse width mapping, the
 * settle time, and the sweep plan, run against a servo that goes where its pulse says. Built with
 * the default settings: limits 0…180° (head −90…+90°), 1000…2000 µs, 0.1 s/60°.
 */
#include "servo.h"
#include "protocol.h"
#include "tinytest.h"

#include <stdio.h>
#include <stdlib.h>

#define MAX_MSGS 2000

static char msgs[MAX_MSGS][PROTO_OUT_CAP];
static int n_msgs;
static head_t H;

/* Records a message as its body, after checking its framing and CRC. */
static void record(void *ctx, const dev_msg *m)
{
    (void)ctx;
    char line[PROTO_OUT_CAP];
    uint8_t n = proto_encode(m, line);
    CHECK(n > 7 && line[0] == '$' && line[n - 1] == '\n' && line[n - 6] == '*');
    line[n - 6] = '\0';
    char crc[5];
    snprintf(crc, sizeof crc, "%04X", proto_crc16(line + 1, strlen(line + 1)));
    CHECK(strncmp(line + n - 5, crc, 4) == 0);
    if (n_msgs < MAX_MSGS) {
        strcpy(msgs[n_msgs++], line + 1);
    }
}

static void fresh(void)
{
    n_msgs = 0;
    head_init(&H, "0123456789ABCDEF", record, 0);
}

static void command(const char *body)
{
    char line[200];
    snprintf(line, sizeof line, "$%s*%04X", body, proto_crc16(body, strlen(body)));
    proto_cmd c;
    char text[PROTO_TEXT_MAX + 1];
    uint8_t code = proto_parse_command(line, (uint8_t)strlen(line), &c, text);
    if (code != ERR_NONE) {
        TT_FAIL("command %s: %s", body, text);
        return;
    }
    head_command(&H, &c);
}

/* What the servo does with the head's moves: the shaft angle of every ping (from the pulse width
 * sent, as the emulated board reads it), and the widest pulse and narrowest pulse sent. */
typedef struct {
    int pings;
    int32_t aims[MAX_MSGS];
    uint16_t pulse_lo, pulse_hi;
    int moves;
    uint32_t settle_total;
    uint16_t settle_first;
} run_log;

/* Runs the head until n pings have been made, each answered with echo_us (0 = none). */
static void run(run_log *L, int n, uint16_t echo_us)
{
    uint16_t pulse = 0;
    L->pulse_lo = 0xFFFF;
    L->pulse_hi = 0;
    for (int guard = 0; L->pings < n && guard < 100000; guard++) {
        uint8_t a = head_next(&H);
        if (a == HEAD_ACT_MOVE) {
            pulse = servo_pulse_ticks_of_head(head_angle_cdeg(&H));
            L->pulse_lo = pulse < L->pulse_lo ? pulse : L->pulse_lo;
            L->pulse_hi = pulse > L->pulse_hi ? pulse : L->pulse_hi;
            if (L->moves == 0) {
                L->settle_first = H.settle;
            }
            L->moves++;
            L->settle_total += H.settle;
        } else if (a == HEAD_ACT_PING) {
            CHECK(pulse != 0); /* never a ping before the servo was sent somewhere */
            /* The shaft's angle from the pulse: 0.5 µs ticks, 2000..4000 for 0..180°. */
            L->aims[L->pings++] = (int32_t)(pulse - 3000) * 9;
            head_ping_done(&H, echo_us, false, 1000u + (uint32_t)L->pings);
        } else {
            break;
        }
    }
}

static void pulse_widths(void)
{
    CHECK_INT(servo_pulse_ticks(0), 2000);      /* 1000 µs at 0° */
    CHECK_INT(servo_pulse_ticks(9000), 3000);   /* 1500 µs in the middle */
    CHECK_INT(servo_pulse_ticks(18000), 4000);  /* 2000 µs at 180° */
    CHECK_INT(servo_pulse_ticks(4500), 2500);
    CHECK_INT(servo_pulse_ticks(150), 2017);    /* 1.5°: 16.67 ticks, rounded */
    /* Never beyond the limits, whatever is asked. */
    CHECK_INT(servo_pulse_ticks(-1000), 2000);
    CHECK_INT(servo_pulse_ticks(19000), 4000);
    /* The head angle is the servo's − 90°. */
    CHECK_INT(servo_pulse_ticks_of_head(-9000), 2000);
    CHECK_INT(servo_pulse_ticks_of_head(0), 3000);
    CHECK_INT(servo_pulse_ticks_of_head(8700), 3967);
    /* Monotonic over the whole travel. */
    for (int32_t c = 1; c <= 18000; c++) {
        CHECK(servo_pulse_ticks(c) >= servo_pulse_ticks(c - 1));
    }
}

static void settle_times(void)
{
    /* One PWM frame (20 ms) for the pulse to take effect, the turn at 0.1 s/60° (rounded up), and
     * 20 ms of ringing. */
    CHECK_INT(servo_settle_ms(0), 40);
    CHECK_INT(servo_settle_ms(150), 43);   /* 1.5°: 2.5 ms */
    CHECK_INT(servo_settle_ms(6000), 140); /* 60°: 100 ms */
    CHECK_INT(servo_settle_ms(18000), 340);
}

static void geometry(void)
{
    CHECK_INT(SERVO_READINGS, 30);
    CHECK_INT(servo_centre_cdeg(0), -8700);
    CHECK_INT(servo_centre_cdeg(29), 8700);
    CHECK_INT(servo_cdeg_of_q(0), -9000);
    CHECK_INT(servo_cdeg_of_q(SERVO_UNITS), 9000);
    /* Pings at centre ∓ 2.25°, ∓ 0.75° in the order of motion. */
    CHECK_INT(servo_cdeg_of_q(servo_ping_q(0, 0, 1)), -8925);
    CHECK_INT(servo_cdeg_of_q(servo_ping_q(0, 3, 1)), -8475);
    CHECK_INT(servo_cdeg_of_q(servo_ping_q(0, 0, -1)), -8475);
}

static void hello_says_servo_limits_and_step(void)
{
    fresh();
    head_send_hello(&H);
    CHECK_INT(n_msgs, 1);
    CHECK_STR(msgs[0], "HELLO,2,sonar-head 0.2.0 servo,0123456789ABCDEF,150,4,-9000,9000");
}

static void full_scan_sweeps_limit_to_limit_and_back(void)
{
    fresh();
    command("SCAN,FULL");
    static run_log L;
    memset(&L, 0, sizeof L);
    run(&L, 2 * 30 * 4, 1000);
    CHECK_INT(L.pings, 240);
    /* The first move may have to turn the whole 180°; every other one is a 1.5° step. */
    CHECK_INT(L.settle_first, 340);
    CHECK_INT(L.moves, 1 + 2 * (30 * 4 - 1));
    CHECK_INT(L.settle_total, 340 + 43 * 2 * (30 * 4 - 1));
    /* Never beyond the servo's travel. */
    CHECK(L.pulse_lo >= 2000 && L.pulse_hi <= 4000);
    /* Up from −89.25° to +89.25°, then back the same way; a pulse tick (0.5 µs) is 0.09°, so
     * the shaft is within half of one (4.5 cdeg) of each ping's angle. */
    for (int k = 0; k < 120; k++) {
        int32_t up = -8925 + 150 * k;
        CHECK(labs((long)(L.aims[k] - up)) <= 5);
        CHECK_INT(L.aims[239 - k], L.aims[k]);
    }
    CHECK_STR(msgs[0], "ACK,SCAN");
    CHECK_STR(msgs[1], "SWP,START,1,+,F,-8700,8700");
    CHECK_STR(msgs[2], "RD,0,1004,1,+,-8700,4,1000,1000,1000,1000");
    CHECK_STR(msgs[31], "RD,29,1120,1,+,8700,4,1000,1000,1000,1000");
    CHECK_STR(msgs[32], "SWP,END,1");
    CHECK_STR(msgs[33], "SWP,START,2,-,F,8700,-8700");
    CHECK_STR(msgs[34], "RD,30,1124,2,-,8700,4,1000,1000,1000,1000");
    CHECK_STR(msgs[63], "RD,59,1240,2,-,-8700,4,1000,1000,1000,1000");
    CHECK_STR(msgs[64], "SWP,END,2");
}

static void local_scan_and_stop(void)
{
    fresh();
    command("SCAN,FULL");
    static run_log L;
    memset(&L, 0, sizeof L);
    run(&L, 4 * 20, 0); /* stops at +29.25°, sweep 1 */
    n_msgs = 0;
    /* A segment: the sweep under way ends; the head starts from the segment's nearer end. */
    command("SCAN,LOCAL,-1000,1000");
    CHECK_STR(msgs[0], "ACK,SCAN");
    CHECK_STR(msgs[1], "SWP,END,1");
    CHECK_STR(msgs[2], "SWP,START,2,-,L,900,-900");
    memset(&L, 0, sizeof L);
    run(&L, 4 * 4, 0);
    CHECK(labs((long)(L.aims[0] - 1125)) <= 5);
    CHECK(labs((long)(L.aims[15] + 1125)) <= 5);
    CHECK_STR(msgs[3], "RD,20,1004,2,-,900,4,0,0,0,0");
    CHECK_STR(msgs[7], "SWP,END,2");
    n_msgs = 0;
    command("STOP");
    CHECK_STR(msgs[0], "ACK,STOP");
    CHECK_STR(msgs[1], "SWP,END,3");
    CHECK_INT(head_next(&H), HEAD_ACT_NONE);
    command("STATUS");
    CHECK_STR(msgs[2], "ST,IDLE,-1125,-,3");
    /* Beyond the servo's limits, or no reading centre inside: refused, nothing moves. */
    n_msgs = 0;
    command("SCAN,LOCAL,-10000,0");
    CHECK_STR(msgs[0], "ERR,RANGE,segment outside the limits -9000..9000");
    command("SCAN,LOCAL,100,200");
    CHECK_STR(msgs[1], "ERR,RANGE,no reading centre in 100..200");
    CHECK_INT(head_next(&H), HEAD_ACT_NONE);
}

static void silent_sensor_reported_once_per_sweep(void)
{
    fresh();
    command("SCAN,FULL");
    for (int i = 0; i < 8; i++) {
        while (head_next(&H) == HEAD_ACT_MOVE) {
        }
        head_ping_done(&H, 0, true, 0);
    }
    CHECK_STR(msgs[2], "ERR,HARDWARE,sensor silent");
    int errs = 0;
    for (int i = 0; i < n_msgs; i++) {
        errs += strncmp(msgs[i], "ERR", 3) == 0;
    }
    CHECK_INT(errs, 1);
    CHECK(head_busy(&H)); /* it sweeps on: the driver decides what to do */
}

void servo_tests(void)
{
    RUN(pulse_widths);
    RUN(settle_times);
    RUN(geometry);
    RUN(hello_says_servo_limits_and_step);
    RUN(full_scan_sweeps_limit_to_limit_and_back);
    RUN(local_scan_and_stop);
    RUN(silent_sensor_reported_once_per_sweep);
}
