/*
 * State machine tests, against a simulated board: a motor whose true position is counted in
 * microsteps, limit switches that close exactly at ±150° (as the emulated board does), and a
 * transducer that records where it was aimed. The runner does what main.c does, minus the
 * waiting. Most tests are the Rust model's (simulator/src/firmware.rs) with the same message
 * indices, so the wire behaviour is the same.
 */
#include "motion.h"
#include "protocol.h"
#include "tinytest.h"

#include <stdlib.h>

static const motor_ratio PAPER = {96UL * 5, 1, 0};
static const motor_ratio BYJ48 = {1650688UL, 405, 2};
static const motor_ratio NEMA17 = {3200UL, 1, 2};

#define MAX_MSGS 4000
#define MAX_AIMS 4000

typedef struct {
    const motor_ratio *r;
    int32_t m_true;        /* true motor position, microsteps from 0° (the board's grid) */
    int32_t m_zero;        /* where the MIN switch closes: the last microstep at or below −150° */
    bool switches;         /* the switches are wired */
    bool max_missing;      /* the MAX switch never closes */
    bool min_stuck;        /* the MIN switch is always closed */
    bool max_stuck;        /* the MAX switch is always closed */
    int32_t m_lowest, m_highest; /* the true motor positions reached, microsteps */
    bool silent;           /* the sensor never answers */
    uint32_t time_ms;
    int n_msgs;
    char msgs[MAX_MSGS][PROTO_OUT_CAP];
    int n_aims;
    int32_t aims[MAX_AIMS]; /* true angle of each ping, cdeg */
    long steps;
} board;

static board B;
static head_t H;

/* Records a message as its body, after checking its framing. */
static void record(void *ctx, const dev_msg *m)
{
    board *b = ctx;
    char line[PROTO_OUT_CAP];
    uint8_t n = proto_encode(m, line);
    CHECK(n > 7 && line[0] == '$' && line[n - 1] == '\n' && line[n - 6] == '*');
    line[n - 6] = '\0';
    char crc[5];
    snprintf(crc, sizeof crc, "%04X", proto_crc16(line + 1, strlen(line + 1)));
    CHECK(strncmp(line + n - 5, crc, 4) == 0);
    if (b->n_msgs < MAX_MSGS) {
        strcpy(b->msgs[b->n_msgs++], line + 1);
    }
}

/* The switches close exactly at ±150° and beyond, compared exactly (like the emulated board):
 * m · 360 · DEN against ±150 · NUM. */
static uint8_t closed(const board *b)
{
    if (!b->switches) {
        return 0;
    }
    int64_t x = (int64_t)b->m_true * 360 * b->r->den;
    uint8_t m = 0;
    if (x <= -150LL * b->r->num || b->min_stuck) {
        m |= HEAD_SW_MIN;
    }
    if ((x >= 150LL * b->r->num && !b->max_missing) || b->max_stuck) {
        m |= HEAD_SW_MAX;
    }
    return m;
}

static int32_t true_cdeg(const board *b)
{
    int64_t x = (int64_t)b->m_true * 36000 * b->r->den;
    int64_t n = b->r->num;
    return (int32_t)(x >= 0 ? (x + n / 2) / n : -((-x + n / 2) / n));
}

/* Head position relative to the MIN switch, as the firmware counts it once homed. */
static int32_t rel(void)
{
    return B.m_true - B.m_zero;
}

/* Power-on with the head at angle start_cdeg (true position, on the microstep grid). */
static void boot(const motor_ratio *r, int32_t start_cdeg)
{
    memset(&B, 0, sizeof B);
    B.r = r;
    B.switches = true;
    int64_t x = (int64_t)start_cdeg * r->num;
    int64_t d = 36000LL * r->den;
    B.m_true = (int32_t)(x >= 0 ? (x + d / 2) / d : -((-x + d / 2) / d));
    /* floor(−150° / microstep) */
    int64_t z = -150LL * r->num;
    int64_t zd = 360LL * r->den;
    B.m_zero = (int32_t)(z >= 0 ? z / zd : -((-z + zd - 1) / zd));
    B.m_lowest = B.m_highest = B.m_true;
    head_init(&H, r, "00112233AABBCCDD", record, &B);
}

/* One action of the main loop; false when idle. */
static bool act(void)
{
    uint8_t a = head_next(&H);
    if (a == HEAD_ACT_STEP) {
        if (head_check_switches(&H, closed(&B), H.step_dir)) {
            return true;
        }
        B.m_true += H.step_dir;
        B.steps++;
        if (B.m_true < B.m_lowest) {
            B.m_lowest = B.m_true;
        }
        if (B.m_true > B.m_highest) {
            B.m_highest = B.m_true;
        }
        head_stepped(&H);
        B.time_ms += 2;
        head_check_switches(&H, closed(&B), H.step_dir);
        return true;
    }
    if (a == HEAD_ACT_PING) {
        if (B.n_aims < MAX_AIMS) {
            B.aims[B.n_aims++] = true_cdeg(&B);
        }
        B.time_ms += 50;
        head_ping_done(&H, B.silent ? 0 : 5823, B.silent, B.time_ms);
        return true;
    }
    return false;
}

/* Acts until n messages came since `from` (or the head idles, or runs away). */
static int run(int from, int n)
{
    for (long i = 0; i < 5000000L; i++) {
        if (B.n_msgs - from >= n) {
            return B.n_msgs - from;
        }
        if (!act()) {
            return B.n_msgs - from;
        }
    }
    TT_FAIL("runaway");
    return B.n_msgs - from;
}

/* Runs until idle. */
static void settle(void)
{
    for (long i = 0; i < 5000000L && act(); i++) {
    }
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

static const char *msg(int i)
{
    return i < B.n_msgs ? B.msgs[i] : "<none>";
}

static bool starts(int i, const char *prefix)
{
    return strncmp(msg(i), prefix, strlen(prefix)) == 0;
}

/* Boots and homes the paper head at −30°; the message log is cleared afterwards. */
static void homed(const motor_ratio *r)
{
    boot(r, -3000);
    settle();
    CHECK_INT(B.n_msgs, 1);
    CHECK_STR(msg(0), "LIM,MIN");
    B.n_msgs = 0;
    B.n_aims = 0;
}

/* Field k (0-based) of an RD body as a number. */
static long rd_field(int i, int k)
{
    const char *p = msg(i);
    for (int f = 0; f < k && p; f++) {
        p = strchr(p, ',');
        if (p) {
            p++;
        }
    }
    return p ? strtol(p, NULL, 10) : -999999;
}

/* ---- boot and homing ------------------------------------------------------------------------- */

static void boot_homes_clockwise_to_the_min_switch(void)
{
    boot(&PAPER, 3000);
    command("HELLO,2");
    CHECK_STR(msg(0), "HELLO,2,sonar-head 0.2.0,00112233AABBCCDD,150,4,-15000,15000");
    command("STATUS");
    CHECK_STR(msg(1), "ST,HOMING,15000,-,0"); /* assumed at the far end until MIN is found */
    run(B.n_msgs, 1);
    CHECK_STR(msg(2), "LIM,MIN");
    CHECK_INT(B.steps, 240); /* 180° at 0.75° per half step */
    CHECK_INT(rel(), 0);
    CHECK(!head_busy(&H));
    command("STATUS");
    CHECK_STR(msg(3), "ST,IDLE,-15000,+,0"); /* the Rust model's power-on state */
}

static void boot_on_the_min_switch_leaves_it_and_comes_back(void)
{
    boot(&PAPER, -15000);
    settle();
    CHECK_INT(B.n_msgs, 1);
    CHECK_STR(msg(0), "LIM,MIN");
    CHECK_INT(rel(), 0);
    CHECK_INT(B.steps, 10); /* off by one half step, 4 more, 5 back */
}

static void boot_beyond_the_min_switch_homes_onto_it(void)
{
    /* Powered on 5° past the switch (moved by hand): the closed switch is not home. */
    boot(&PAPER, -15500);
    settle();
    CHECK_INT(B.n_msgs, 1);
    CHECK_STR(msg(0), "LIM,MIN");
    CHECK_INT(rel(), 0);
    command("SCAN,FULL");
    run(B.n_msgs, 53); /* ACK, SWP,START, 50 RD, LIM,MAX (with what the same action sends) */
    CHECK_STR(msg(53), "LIM,MAX"); /* at its place: the head knew where it was */
    CHECK_INT(B.aims[0], -14925);  /* the first ping where it belongs */
    for (int i = 0; i < B.n_msgs; i++) {
        CHECK(!starts(i, "ERR"));
    }
}

/* The head stopped on a fault: scans are refused, STOP changes nothing, nothing moves. */
static void check_stopped(void)
{
    int n = B.n_msgs;
    long steps = B.steps;
    int err = n - 1;
    while (err >= 0 && !starts(err, "ERR,HARDWARE,")) {
        err--;
    }
    CHECK(err >= 0);
    command("SCAN,FULL"); /* answered with the fault again */
    CHECK_STR(msg(n), msg(err));
    command("SCAN,LOCAL,-3000,3000");
    CHECK_STR(msg(n + 1), msg(err));
    command("STOP");
    CHECK_STR(msg(n + 2), "ACK,STOP");
    command("STATUS");
    CHECK(starts(n + 3, "ST,FAULT,"));
    CHECK(!act());
    CHECK_INT(B.steps, steps);
    CHECK(head_busy(&H)); /* the LED stays on */
}

static void a_stuck_min_switch_is_a_hardware_fault(void)
{
    boot(&PAPER, -15000);
    B.min_stuck = true;
    settle();
    CHECK_INT(B.n_msgs, 2);
    CHECK_STR(msg(0), "ERR,HARDWARE,MIN switch stuck closed (still closed 30 deg off it)");
    CHECK_STR(msg(1), "ST,FAULT,15000,+,0"); /* the angle assumed while homing */
    CHECK_INT(B.steps, 40);
    check_stopped();
}

static void a_stuck_min_switch_never_turns_the_head_past_max(void)
{
    /* Powered on near MAX: leaving the (stuck) MIN switch runs into MAX, which stops it. */
    boot(&PAPER, 14000);
    B.min_stuck = true;
    settle();
    CHECK_STR(msg(0), "ERR,HARDWARE,both limit switches closed (one stuck? wiring shorted?)");
    CHECK(starts(1, "ST,FAULT,"));
    CHECK_INT(B.n_msgs, 2);
    CHECK_INT(true_cdeg(&B), 15000); /* stopped on the MAX switch */
    CHECK(B.m_highest <= B.m_true);
    check_stopped();
}

static void a_stuck_max_switch_is_found_at_home(void)
{
    boot(&PAPER, 0);
    B.max_stuck = true;
    settle();
    CHECK_INT(B.n_msgs, 2);
    CHECK_STR(msg(0), "ERR,HARDWARE,both limit switches closed (one stuck? wiring shorted?)");
    CHECK(starts(1, "ST,FAULT,"));
    CHECK_INT(rel(), 0); /* at the MIN switch, never turned counter-clockwise */
    CHECK_INT(B.m_highest, 0); /* the start, 0° */
    check_stopped();
}

static void both_switches_closed_while_standing_is_a_fault(void)
{
    homed(&PAPER);
    B.max_stuck = true;
    CHECK(head_check_switches(&H, closed(&B), 0));
    CHECK_STR(msg(0), "ERR,HARDWARE,both limit switches closed (one stuck? wiring shorted?)");
    CHECK_STR(msg(1), "ST,FAULT,-15000,+,0");
    check_stopped();
}

static void homing_gives_up_after_one_sweep_and_waits_for_reset(void)
{
    boot(&PAPER, 0);
    B.switches = false; /* MIN not wired */
    settle();
    CHECK_INT(B.n_msgs, 2);
    CHECK_STR(msg(0), "ERR,HARDWARE,MIN switch not found in 315 deg of homing (dead switch? wiring?)");
    CHECK_STR(msg(1), "ST,FAULT,-15000,-,0"); /* 315° from an assumed +150°, clamped */
    CHECK_INT(B.steps, 420); /* 315° = one sweep + 15° */
    CHECK_INT(B.m_true - B.m_lowest, 0);
    check_stopped();
    /* A person fixed the switch and sends RESET: the head homes again, then a scan runs. */
    B.switches = true;
    B.m_true = B.m_zero + motion_motor_of(&PAPER, 100);
    int n = B.n_msgs;
    command("RESET");
    CHECK_STR(msg(n), "ACK,RESET");
    command("STATUS");
    CHECK_STR(msg(n + 1), "ST,HOMING,15000,-,0");
    command("SCAN,FULL"); /* acknowledged during homing, started when it ends */
    CHECK_STR(msg(n + 2), "ACK,SCAN");
    run(B.n_msgs, 2);
    CHECK_STR(msg(n + 3), "LIM,MIN");
    CHECK_STR(msg(n + 4), "SWP,START,1,+,F,-14700,14700");
}

static void reset_mid_sweep_ends_it_rehomes_and_sweep_ids_go_on(void)
{
    homed(&PAPER);
    command("SCAN,FULL");
    run(0, 10);
    int n = B.n_msgs;
    command("RESET");
    CHECK_STR(msg(n), "ACK,RESET");
    CHECK_STR(msg(n + 1), "SWP,END,1");
    settle();
    CHECK_STR(msg(n + 2), "LIM,MIN");
    CHECK_INT(B.n_msgs, n + 3); /* homed, idle: the scan is the host's to send again */
    CHECK_INT(rel(), 0);
    command("SCAN,FULL");
    run(n + 3, 2);
    CHECK_STR(msg(n + 4), "SWP,START,2,+,F,-14700,14700");
}

static void commands_during_homing(void)
{
    boot(&PAPER, 0);
    for (int i = 0; i < 10; i++) {
        act();
    }
    command("STATUS");
    CHECK_STR(msg(0), "ST,HOMING,14250,-,0");
    command("HELLO,1");
    CHECK_STR(msg(1), "ERR,VERSION,host speaks version 1; device speaks 2");
    command("SCAN,LOCAL,-16000,0");
    CHECK(starts(2, "ERR,RANGE,"));
    command("SCAN,LOCAL,-3000,3000");
    CHECK_STR(msg(3), "ACK,SCAN");
    command("SCAN,FULL"); /* replaces the waiting scan; no sweep was open */
    CHECK_STR(msg(4), "ACK,SCAN");
    CHECK_INT(B.n_msgs, 5);
    run(B.n_msgs, 2);
    CHECK_STR(msg(5), "LIM,MIN");
    CHECK_STR(msg(6), "SWP,START,1,+,F,-14700,14700");
}

static void stop_during_homing_drops_the_scan_but_homes(void)
{
    boot(&PAPER, 0);
    act();
    command("SCAN,FULL");
    command("STOP");
    CHECK_STR(msg(0), "ACK,SCAN");
    CHECK_STR(msg(1), "ACK,STOP");
    settle();
    CHECK_INT(B.n_msgs, 3);
    CHECK_STR(msg(2), "LIM,MIN");
    CHECK_INT(rel(), 0);
}

/* ---- the Rust model's tests ------------------------------------------------------------------ */

static void full_sweeps_run_between_the_limits_for(const motor_ratio *r)
{
    homed(r);
    command("SCAN,FULL");
    CHECK_STR(msg(0), "ACK,SCAN");
    B.n_msgs = 0;
    run(0, 2 * 54);
    CHECK_STR(msg(0), "SWP,START,1,+,F,-14700,14700");
    CHECK_STR(msg(51), "LIM,MAX");
    CHECK_STR(msg(52), "SWP,END,1");
    CHECK_STR(msg(53), "SWP,START,2,-,F,14700,-14700");
    CHECK_STR(msg(104), "LIM,MIN");
    CHECK_STR(msg(105), "SWP,END,2");
    CHECK_STR(msg(106), "SWP,START,3,+,F,-14700,14700");
    int seq = 0;
    for (int s = 0; s < 2; s++) {
        int base = s == 0 ? 1 : 54;
        for (int k = 0; k < 50; k++) {
            int i = base + k;
            CHECK(starts(i, "RD,"));
            CHECK_INT(rd_field(i, 1), seq++);
            CHECK_INT(rd_field(i, 3), s + 1);
            CHECK_INT(rd_field(i, 5), s == 0 ? -14700 + 600 * k : 14700 - 600 * k);
            CHECK(strstr(msg(i), s == 0 ? ",+," : ",-,") != NULL);
            CHECK(strstr(msg(i), ",4,5823,5823,5823,5823") != NULL);
        }
    }
    /* Pings 1.5° apart around each centre, in the order of motion, within half a microstep. */
    const int32_t first[4] = {-14925, -14775, -14625, -14475};
    const int32_t back[4] = {14925, 14775, 14625, 14475};
    /* Homing's zero lies up to a microstep below −150°, plus half a microstep of rounding. */
    int32_t tol = (int32_t)((54000LL * r->den + r->num - 1) / r->num) + 1;
    for (int j = 0; j < 4; j++) {
        CHECK(labs(B.aims[j] - first[j]) <= tol);
        CHECK(labs(B.aims[200 + j] - back[j]) <= tol);
    }
    for (int i = 0; i < 400; i++) {
        int k = (i % 200) / 4, j = i % 4;
        int32_t centre = i < 200 ? -14700 + 600 * k : 14700 - 600 * k;
        int32_t expect = centre + (i < 200 ? 1 : -1) * (150 * j - 225);
        CHECK(labs(B.aims[i] - expect) <= tol);
    }
}

static void full_sweeps_run_between_the_limits(void)
{
    full_sweeps_run_between_the_limits_for(&PAPER);
    /* The paper head's aims are exact. */
    CHECK_INT(B.aims[0], -14925);
    CHECK_INT(B.aims[3], -14475);
    CHECK_INT(B.aims[200], 14925);
}

static void full_sweeps_28byj48_and_nema17(void)
{
    full_sweeps_run_between_the_limits_for(&BYJ48);
    full_sweeps_run_between_the_limits_for(&NEMA17);
}

static void reading_times_follow_the_device_clock(void)
{
    homed(&PAPER);
    command("SCAN,FULL");
    run(B.n_msgs, 4);
    CHECK(starts(2, "RD,0,"));
    CHECK(starts(3, "RD,1,"));
    long t0 = rd_field(2, 2), t1 = rd_field(3, 2);
    CHECK(t1 > t0);
    CHECK_INT(t1 - t0, 4 * 50 + 8 * 2); /* 4 pings and 8 half steps of the test clock */
}

static void full_scan_from_between_the_limits_first_drives_on_to_the_limit_ahead(void)
{
    homed(&PAPER);
    command("SCAN,LOCAL,-3000,3000");
    run(0, 4); /* ACK, SWP,START and two readings, going CCW */
    command("STOP");
    int before = B.n_aims;
    command("SCAN,FULL");
    int n = B.n_msgs;
    CHECK_STR(msg(n - 3), "ACK,STOP");
    CHECK_STR(msg(n - 2), "SWP,END,1");
    CHECK_STR(msg(n - 1), "ACK,SCAN");
    run(n, 2);
    CHECK_STR(msg(n), "LIM,MAX");
    CHECK_INT(B.n_aims, before); /* no pings on the way */
    CHECK_STR(msg(n + 1), "SWP,START,2,-,F,14700,-14700");
}

static void local_scan_sweeps_back_and_forth_over_the_segment(void)
{
    homed(&PAPER);
    command("SCAN,LOCAL,-3000,3000");
    CHECK_STR(msg(0), "ACK,SCAN");
    B.n_msgs = 0;
    run(0, 3 * 12);
    for (int i = 0; i < B.n_msgs; i++) {
        CHECK(!starts(i, "LIM"));
    }
    CHECK_STR(msg(0), "SWP,START,1,+,L,-2700,2700");
    CHECK_STR(msg(11), "SWP,END,1");
    CHECK_STR(msg(12), "SWP,START,2,-,L,2700,-2700");
    CHECK_STR(msg(23), "SWP,END,2");
    CHECK_STR(msg(24), "SWP,START,3,+,L,-2700,2700");
    for (int k = 0; k < 10; k++) {
        CHECK_INT(rd_field(1 + k, 5), -2700 + 600 * k);
        CHECK_INT(rd_field(13 + k, 5), 2700 - 600 * k);
    }
    /* No pings on the way from the MIN limit; the segment starts 2.25° below its first centre. */
    CHECK_INT(B.aims[0], -2925);
    CHECK_INT(B.aims[39], 2925);
    CHECK_INT(B.aims[40], 2925);
}

static void local_scan_outside_the_limits_or_between_centres_is_refused(void)
{
    homed(&PAPER);
    const char *bad[] = {"SCAN,LOCAL,-16000,0", "SCAN,LOCAL,0,15001", "SCAN,LOCAL,100,200",
                         "SCAN,LOCAL,14800,15000"};
    for (int i = 0; i < 4; i++) {
        command(bad[i]);
        CHECK(starts(i, "ERR,RANGE,"));
    }
    CHECK_STR(msg(1), "ERR,RANGE,segment outside the limits -15000..15000");
    CHECK_STR(msg(2), "ERR,RANGE,no reading centre in 100..200");
    CHECK(!head_busy(&H));
    command("SCAN,LOCAL,200,400"); /* one centre is fine */
    CHECK_INT(B.n_msgs, 5);
    CHECK_STR(msg(4), "ACK,SCAN");
    int n = B.n_msgs;
    run(n, 8);
    for (int i = n; i < B.n_msgs; i++) {
        if (starts(i, "RD,")) {
            CHECK_INT(rd_field(i, 5), 300);
        }
    }
}

static void stop_ends_the_sweep_and_holds_the_position(void)
{
    homed(&PAPER);
    command("SCAN,FULL");
    run(0, 3); /* ACK, SWP,START, RD */
    command("STATUS");
    CHECK_STR(msg(3), "ST,FULL,-14475,+,1");
    /* Half-way through the second reading. */
    int n = B.n_msgs;
    while (B.n_aims < 6) {
        act();
    }
    CHECK_INT(B.n_msgs, n);
    command("STOP");
    CHECK_STR(msg(n), "ACK,STOP");
    CHECK_STR(msg(n + 1), "SWP,END,1");
    CHECK(!act());
    int32_t aim = B.aims[B.n_aims - 1];
    CHECK_INT(aim, -14175); /* ping 2 of reading 1 */
    command("STATUS");
    char expect[64];
    snprintf(expect, sizeof expect, "ST,IDLE,%d,+,1", aim);
    CHECK_STR(msg(n + 2), expect);
    command("STOP");
    CHECK_INT(B.n_msgs, n + 4);
    CHECK_STR(msg(n + 3), "ACK,STOP");
}

static void a_new_scan_replaces_the_running_one(void)
{
    homed(&PAPER);
    command("SCAN,FULL");
    run(0, 5);
    command("SCAN,LOCAL,0,1000");
    int n = B.n_msgs;
    CHECK_STR(msg(n - 2), "ACK,SCAN");
    CHECK_STR(msg(n - 1), "SWP,END,1");
    run(n, 1);
    CHECK_STR(msg(n), "SWP,START,2,+,L,300,900");
}

static void stop_during_the_run_on_closes_the_sweep(void)
{
    /* 28BYJ-48: the run-on from the last ping to the switch is 8 half steps. */
    homed(&BYJ48);
    command("SCAN,FULL");
    while (!(B.n_msgs > 0 && starts(B.n_msgs - 1, "RD,") && rd_field(B.n_msgs - 1, 5) == 14700)) {
        if (!act()) {
            break;
        }
    }
    int n = B.n_msgs;
    act(); /* one half step of the run-on */
    CHECK_INT(B.n_msgs, n);
    command("STOP");
    CHECK_STR(msg(n), "ACK,STOP");
    CHECK_STR(msg(n + 1), "SWP,END,1");
    /* The 1.5° step under way ends (at the switch, which says so); nothing more. */
    settle();
    CHECK_INT(B.n_msgs, n + 3);
    CHECK_STR(msg(n + 2), "LIM,MAX");
    command("STATUS");
    /* The angle comes from the motor position reached: 3396 half steps = 299.96°. */
    CHECK_STR(msg(n + 3), "ST,IDLE,14996,-,1");
}

/* ---- v2 additions: hardware errors ----------------------------------------------------------- */

static void switch_closing_early_stops_the_head_without_correcting(void)
{
    homed(&PAPER);
    command("SCAN,FULL");
    run(0, 53); /* the first sweep, LIM,MAX, SWP,END */
    CHECK_STR(msg(52), "LIM,MAX");
    /* The head slipped 15° clockwise (missed steps), or the switch moved: the switch closes 20
     * units before the step count says it should. Which one is wrong nothing can tell. */
    B.m_true -= 20;
    int n = B.n_msgs;
    settle();
    int err = -1;
    for (int k = n; k < B.n_msgs; k++) {
        if (starts(k, "ERR")) {
            err = k;
            break;
        }
    }
    CHECK_STR(msg(err),
              "ERR,HARDWARE,MIN switch closed at -13500 cdeg: 1500 cdeg early (switch moved? missed steps?)");
    CHECK(starts(err - 1, "RD,"));
    /* The switch closed between the pings of the reading at −135°: the last whole one is −129°. */
    CHECK_INT(rd_field(err - 1, 5), -12900);
    CHECK_STR(msg(err + 1), "SWP,END,2");
    CHECK_STR(msg(err + 2), "ST,FAULT,-13500,-,2");
    CHECK_INT(B.n_msgs, err + 3);
    for (int k = n; k < B.n_msgs; k++) {
        CHECK(!starts(k, "LIM"));
    }
    CHECK(rel() != H.m); /* not "corrected" to the switch */
    check_stopped();
}

static void switch_closing_within_a_step_of_its_limit_just_reverses(void)
{
    homed(&PAPER);
    command("SCAN,FULL");
    run(0, 53);
    B.m_true -= 2; /* 1.5°: within tolerance */
    int n = B.n_msgs;
    int lim = -1;
    for (long i = 0; i < 100000 && lim < 0; i++) {
        act();
        for (int k = n; k < B.n_msgs; k++) {
            if (starts(k, "LIM,MIN")) {
                lim = k;
            }
        }
    }
    CHECK(starts(lim - 1, "RD,"));
    CHECK_INT(rd_field(lim - 1, 5), -14100); /* reading 0 was cut short by the switch */
    run(B.n_msgs, 2);
    CHECK_STR(msg(lim + 1), "SWP,END,2");
    CHECK_STR(msg(lim + 2), "SWP,START,3,+,F,-14700,14700");
    for (int i = 0; i < B.n_msgs; i++) {
        CHECK(!starts(i, "ERR"));
    }
}

static void max_switch_closing_early_during_a_travel(void)
{
    homed(&PAPER);
    command("SCAN,LOCAL,0,3000");
    B.m_true += 300; /* the head is 225° further CCW than it thinks */
    run(0, 3);
    CHECK_STR(msg(0), "ACK,SCAN");
    CHECK_STR(msg(1),
              "ERR,HARDWARE,MAX switch closed at -7500 cdeg: 22500 cdeg early (switch moved? missed steps?)");
    CHECK_STR(msg(2), "ST,FAULT,-7500,+,0");
    CHECK_INT(B.n_msgs, 3);
    check_stopped();
}

static void at_a_limit_without_its_switch_the_head_stops_for(const motor_ratio *r)
{
    homed(r);
    B.max_missing = true;
    command("SCAN,FULL");
    settle();
    int32_t top = B.m_zero + motion_motor_of(r, HEAD_MAX_UNITS);
    int32_t tolerance = motion_motor_of(r, HEAD_SWITCH_TOLERANCE_UNITS) + r->limit_seek;
    CHECK_STR(msg(0), "ACK,SCAN");
    CHECK(starts(51, "RD,49,"));
    char expect[PROTO_OUT_CAP];
    snprintf(expect, sizeof expect,
             "ERR,HARDWARE,MAX switch open at %d cdeg past its limit (dead switch? missed steps?)",
             motion_cdeg_of_motor(r, H.m));
    CHECK_STR(msg(52), expect);
    CHECK_STR(msg(53), "SWP,END,1");
    CHECK(starts(54, "ST,FAULT,15000,+,1"));
    CHECK_INT(B.n_msgs, 55);
    /* Crept on by the tolerance (1.5°) and the motor's rounding at most, then stopped. */
    CHECK_INT(B.m_highest, top + tolerance);
    CHECK_INT(B.m_true, top + tolerance);
    check_stopped();
}

static void at_a_limit_without_its_switch_the_head_stops(void)
{
    at_a_limit_without_its_switch_the_head_stops_for(&PAPER);
    at_a_limit_without_its_switch_the_head_stops_for(&BYJ48);
    at_a_limit_without_its_switch_the_head_stops_for(&NEMA17);
}

static void silent_sensor_is_reported_once_per_sweep(void)
{
    homed(&PAPER);
    B.silent = true;
    command("SCAN,LOCAL,-1000,1000");
    run(0, 10);
    CHECK_STR(msg(0), "ACK,SCAN");
    CHECK(starts(1, "SWP,START,1,"));
    CHECK_STR(msg(2), "ERR,HARDWARE,sensor silent");
    for (int i = 3; i < 7; i++) { /* centres −900, −300, 300, 900 */
        CHECK(starts(i, "RD,"));
        CHECK(strstr(msg(i), ",4,0,0,0,0") != NULL);
    }
    CHECK_STR(msg(7), "SWP,END,1");
    CHECK(starts(8, "SWP,START,2,"));
    CHECK_STR(msg(9), "ERR,HARDWARE,sensor silent");
}

static void commands_mid_move_take_effect_after_the_step(void)
{
    /* 28BYJ-48: a 1.5° step is 16–17 half steps; a command in the middle of one is obeyed at
     * its end, and STATUS reports the angle actually reached. */
    homed(&BYJ48);
    command("SCAN,FULL");
    run(0, 3);
    int n = B.n_msgs;
    for (int i = 0; i < 5; i++) {
        act();
    }
    command("STATUS");
    char expect[64];
    snprintf(expect, sizeof expect, "ST,FULL,%d,+,1", motion_cdeg_of_motor(&BYJ48, H.m));
    CHECK_STR(msg(n), expect);
    CHECK(H.moving);
    command("STOP");
    CHECK_STR(msg(n + 1), "ACK,STOP");
    CHECK_STR(msg(n + 2), "SWP,END,1");
    settle();
    CHECK(!H.moving);
    CHECK_INT(H.m, motion_motor_of(&BYJ48, H.q));
    CHECK_INT(rel(), H.m);
    CHECK(H.q % 2 == 1);
}

static void hello_reply_and_version_refusal(void)
{
    homed(&PAPER);
    command("HELLO,2");
    CHECK_STR(msg(0), "HELLO,2,sonar-head 0.2.0,00112233AABBCCDD,150,4,-15000,15000");
    command("HELLO,3");
    CHECK_STR(msg(1), "ERR,VERSION,host speaks version 3; device speaks 2");
    CHECK(!head_busy(&H));
}

static void unhomed_stop_and_status(void)
{
    boot(&PAPER, 0);
    B.switches = false;
    settle();
    command("STOP");
    CHECK_STR(msg(2), "ACK,STOP");
    CHECK_INT(B.n_msgs, 3);
    CHECK(!act());
}

void head_tests(void)
{
    RUN(boot_homes_clockwise_to_the_min_switch);
    RUN(boot_on_the_min_switch_leaves_it_and_comes_back);
    RUN(boot_beyond_the_min_switch_homes_onto_it);
    RUN(a_stuck_min_switch_is_a_hardware_fault);
    RUN(a_stuck_min_switch_never_turns_the_head_past_max);
    RUN(a_stuck_max_switch_is_found_at_home);
    RUN(both_switches_closed_while_standing_is_a_fault);
    RUN(homing_gives_up_after_one_sweep_and_waits_for_reset);
    RUN(reset_mid_sweep_ends_it_rehomes_and_sweep_ids_go_on);
    RUN(commands_during_homing);
    RUN(stop_during_homing_drops_the_scan_but_homes);
    RUN(full_sweeps_run_between_the_limits);
    RUN(full_sweeps_28byj48_and_nema17);
    RUN(reading_times_follow_the_device_clock);
    RUN(full_scan_from_between_the_limits_first_drives_on_to_the_limit_ahead);
    RUN(local_scan_sweeps_back_and_forth_over_the_segment);
    RUN(local_scan_outside_the_limits_or_between_centres_is_refused);
    RUN(stop_ends_the_sweep_and_holds_the_position);
    RUN(a_new_scan_replaces_the_running_one);
    RUN(stop_during_the_run_on_closes_the_sweep);
    RUN(switch_closing_early_stops_the_head_without_correcting);
    RUN(switch_closing_within_a_step_of_its_limit_just_reverses);
    RUN(max_switch_closing_early_during_a_travel);
    RUN(at_a_limit_without_its_switch_the_head_stops);
    RUN(silent_sensor_is_reported_once_per_sweep);
    RUN(commands_mid_move_take_effect_after_the_step);
    RUN(hello_reply_and_version_refusal);
    RUN(unhomed_stop_and_status);
}
