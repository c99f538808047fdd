/*
 * motion.h — geometry of the head and its state machine, pure and host-testable.
 *
 * Positions: the head position q counts units of 0.75° (half of the paper's 1.5° step) from the
 * MIN limit switch (−150°): the pings of a reading sit on odd units, the limits on even ones
 * (0 and HEAD_MAX_UNITS = 400). The motor position m counts microsteps from the MIN switch; the
 * motor position of head position q is round(q · NUM / (480 · DEN)) where NUM/DEN microsteps make
 * one output revolution, so no rounding error ever accumulates.
 *
 * The state machine behaves on the wire like simulator/src/firmware.rs (the Rust model of this
 * head): the same messages in the same order, the same sweep ids, reading centres and ping
 * positions. At a sweep limit whose switch is still open, the head creeps on by at most
 * HEAD_SWITCH_TOLERANCE_UNITS (1.5°) plus limit_seek microsteps (for a motor whose limit is not a
 * whole number of microsteps) to meet it.
 *
 * The head protects itself (docs/protocol.md, "Hardware faults"): it never travels further than
 * one sweep plus a margin without a switch (homing: HOMING_MAX_DEG; after homing: the limit plus
 * the tolerance). A hardware fault — the MIN switch not found while homing, or stuck closed; both
 * switches closed; a switch still open past its limit; a switch closing more than the tolerance
 * before its limit (the position is NOT "corrected" to it) — stops the head at once: it reports
 * ERR,HARDWARE,<what>, ends the open sweep (SWP,END), reports ST,FAULT, answers a scan with the
 * same ERR,HARDWARE,<what> line (and does not move), and moves only after RESET, which homes it
 * again.
 *
 * It never waits: the caller (main.c, or a test) asks head_next() what to do — one
 * microstep, one ping, or nothing — does it when the hardware timing allows, and reports back.
 */
#ifndef SONAR_MOTION_H
#define SONAR_MOTION_H

#include "config.h"
#include "protocol.h"

#include <stdbool.h>
#include <stdint.h>

/* Microsteps per output revolution as an exact fraction, and how far the head may creep on at a
 * sweep limit whose switch has not closed yet (see head_next). */
typedef struct {
    uint32_t num;
    uint32_t den;
    uint8_t limit_seek; /* microsteps */
} motor_ratio;

/* The configured motor (config.h). */
extern const motor_ratio MOTOR_RATIO;

/* ---- geometry -------------------------------------------------------------------------------- */

/* Motor position (microsteps from MIN) of head position q (units of 0.75° from MIN), rounded to
 * the nearest microstep (halves away from zero). q may be negative. */
int32_t motion_motor_of(const motor_ratio *r, int16_t q);
/* Head angle in centidegrees of motor position m, rounded to the nearest centidegree. */
int32_t motion_cdeg_of_motor(const motor_ratio *r, int32_t m);
/* Microsteps of clockwise travel in HOMING_MAX_DEG (rounded up). */
uint32_t motion_homing_limit(const motor_ratio *r);

/* ULN2003 half-step sequence: the IN1..IN4 bits (bit 0 = IN1) of phase 0..7; phase + 1 is one
 * half step counter-clockwise (angle increasing). */
uint8_t motion_halfstep_pattern(uint8_t phase);

/* Centre of reading i (0 … HEAD_READINGS − 1), centidegrees: −14700 + 600·i. */
int32_t motion_centre_cdeg(uint8_t i);
/* Head position of ping j (0 … HEAD_PINGS − 1, in the order of motion) of reading i, for a sweep
 * in direction dir (+1 CCW, −1 CW): centre ∓ 3, ∓ 1, ± 1, ± 3 units. */
int16_t motion_ping_q(uint8_t i, uint8_t j, int8_t dir);
/* Outermost ping positions of readings first … last. */
void motion_segment_ends(uint8_t first, uint8_t last, int16_t *lo, int16_t *hi);

/* ---- the head state machine ------------------------------------------------------------------ */

typedef void (*head_emit_fn)(void *ctx, const dev_msg *m);

enum { HEAD_IDLE = 0, HEAD_HOMING, HEAD_TRAVEL, HEAD_SWEEP, HEAD_FAULT };
enum { HEAD_ACT_NONE = 0, HEAD_ACT_STEP, HEAD_ACT_PING };
/* Bits of the closed-switch mask passed to head_check_switches. */
#define HEAD_SW_MIN 0x01u
#define HEAD_SW_MAX 0x02u

typedef struct {
    bool full;
    uint8_t first, last; /* reading indices of a local segment */
} head_scan;

typedef struct {
    const motor_ratio *ratio;
    head_emit_fn emit;
    void *ctx;
    const char *head_id; /* 16 hex digits, RAM */
    uint32_t home_limit; /* microsteps of homing travel before giving up */

    uint8_t activity; /* HEAD_IDLE … HEAD_SWEEP */
    head_scan scan;
    bool homed;
    bool pending; /* a scan acknowledged during homing, started when homing ends */
    head_scan pending_scan;
    uint32_t home_travel;
    uint8_t home_phase;       /* HOME_SEEK, HOME_LEAVE or HOME_CLEAR */
    uint32_t home_clear_left; /* HOME_CLEAR: microsteps still to go past the opened switch */

    int16_t q;    /* head position, units of 0.75° from MIN (last position reached) */
    int32_t m;    /* motor position, microsteps from MIN (while homing: from the assumed start) */
    int8_t dir;   /* direction of the last motion, +1 CCW (angle increasing), −1 CW */
    bool moving;  /* a move of at most one 1.5° step to move_to is under way */
    uint8_t seek_left; /* at a limit with its switch open: microsteps left to creep on */
    bool seek_exhausted; /* crept on as far as allowed and the switch is still open */
    int16_t move_to;
    int8_t step_dir; /* direction of the microstep head_next asked for */

    bool planned; /* HEAD_TRAVEL: target computed (at the end of any move under way) */
    int16_t target;
    uint32_t ending; /* HEAD_TRAVEL: sweep still open, closed on arrival (0 = none) */

    uint32_t sweep; /* HEAD_SWEEP: its id */
    int8_t sdir;    /* HEAD_SWEEP: its direction */
    uint8_t k;      /* HEAD_SWEEP: reading in sweep order */
    uint8_t ping;   /* HEAD_SWEEP: next ping of that reading */
    bool ping_out;  /* a ping was asked for and its result is awaited */
    bool silent_reported;

    char fault_text[PROTO_TEXT_MAX + 1]; /* HEAD_FAULT: what it stopped on, sent again to a scan */

    uint32_t last_sweep; /* latest sweep id started, 0 before the first */
    uint32_t seq;        /* RD counter */
    uint16_t echoes[HEAD_PINGS];
} head_t;

/* Homing: seek clockwise until MIN closes. A MIN switch already closed before the first step says
 * only that the head is at or beyond it (it may have powered on past the switch): leave it
 * counter-clockwise until it opens, go on a little (bounce), then seek. */
enum { HOME_SEEK, HOME_LEAVE, HOME_CLEAR };

/* Power-on: not homed, homing (clockwise, from an assumed +150°). Sends nothing. */
void head_init(head_t *h, const motor_ratio *r, const char *head_id, head_emit_fn emit, void *ctx);
/* The unprompted HELLO line (also the reply to HELLO,2). */
void head_send_hello(head_t *h);
/* One command from the PC (already parsed). */
void head_command(head_t *h, const proto_cmd *cmd);
/* What to do next: HEAD_ACT_STEP (one microstep in h->step_dir, then call head_stepped),
 * HEAD_ACT_PING (a ping, then head_ping_done), or HEAD_ACT_NONE. May emit messages
 * (SWP, RD follow-ups, homing failure). Calling it again without acting asks the same thing. */
uint8_t head_next(head_t *h);
/* The microstep asked for was made. */
void head_stepped(head_t *h);
/* Switch check, after a microstep in direction dir (once it has had time to take effect) or before
 * one, or while standing (dir = 0): closed is the mask of closed switches (level, or a closing
 * edge since the last check). Both closed is a fault in any state; otherwise only the switch in
 * the direction of motion counts. Returns true if it acted (homing found, LIM, position set to the
 * limit, reversal, or a fault: the head stopped). */
bool head_check_switches(head_t *h, uint8_t closed, int8_t dir);
/* The ping asked for finished: echo time in µs (0 = no echo); silent = the echo line never rose;
 * now_ms = the device clock. Ignored if a command cancelled the ping meanwhile. */
void head_ping_done(head_t *h, uint16_t echo_us, bool silent, uint32_t now_ms);
/* Whether a scan or homing is under way, or the head stopped on a fault (for the LED). */
bool head_busy(const head_t *h);
/* ST angle: from the motor position reached, clamped to the limits. */
int32_t head_angle_cdeg(const head_t *h);

#endif
