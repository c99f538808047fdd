/*
 * servo.h — the servo head (make HEAD=servo): an SG90/MG90S hobby servo turns an HC-SR04, no limit
 * switches. Pure and host-testable, like motion.h, whose head interface (head_t, head_command,
 * head_next, head_ping_done, …) it implements for this head; main.c links one of the two.
 *
 * Angles: the servo's own angle s runs 0…180° (1000…2000 µs, servo_pulse_ticks); the head angle
 * the protocol speaks is s − 90°, so the servo's middle is the sensor's forward axis (as the hobby
 * dialect's default offset). The sweep limits are the servo's (SERVO_MIN_DEG…SERVO_MAX_DEG, build
 * settings); HELLO announces them with the paper's 1.5° step and four pings per 6° reading.
 *
 * Positions: q counts units of 0.75° from the lower limit, like motion.h: the pings of reading i
 * sit on odd units 4·(2i+1) ∓ 3, ∓ 1, every move between two pings is one 1.5° step. A servo goes
 * where it is told (no steps to count, no switch to find): head_next asks for a move straight to
 * the next ping's position (HEAD_ACT_MOVE) with the time the servo needs to get there
 * (servo_settle_ms), then for the ping. The pulse width is clamped to the limits, whatever q.
 *
 * A full scan sweeps from the limit nearer to the servo to the other one and back, until stopped;
 * a sweep ends after its last reading (there is no switch to reach: no LIM line). Nothing the head
 * could sense is a fault that stops it: an HC-SR04 that never answers is reported once per sweep
 * (ERR,HARDWARE,sensor silent), as by the stepper head. The driver's RESET is acknowledged and
 * ends any scan (there is nothing to home).
 */
#ifndef SONAR_SERVO_H
#define SONAR_SERVO_H

#include "config.h"
#include "protocol.h"

#include <stdbool.h>
#include <stdint.h>

/* ---- servo constants (config.h build settings; the datasheets are cited there) --------------- */

#define SERVO_HEAD_MIN_CDEG ((int32_t)SERVO_MIN_DEG * 100 - 9000)
#define SERVO_HEAD_MAX_CDEG ((int32_t)SERVO_MAX_DEG * 100 - 9000)
#define SERVO_UNITS ((SERVO_HEAD_MAX_CDEG - SERVO_HEAD_MIN_CDEG) / HEAD_UNIT_CDEG)
#define SERVO_READINGS (SERVO_UNITS / (2 * HEAD_PINGS))

_Static_assert(SERVO_MIN_DEG >= 0 && SERVO_MAX_DEG <= 180 && SERVO_MIN_DEG < SERVO_MAX_DEG,
               "SERVO_MIN_DEG and SERVO_MAX_DEG must lie in 0..180, min below max");
_Static_assert((SERVO_MAX_DEG - SERVO_MIN_DEG) % 6 == 0,
               "the servo's sweep must be a whole number of 6 degree readings");
_Static_assert(SERVO_PULSE_MIN_US >= 500 && SERVO_PULSE_MAX_US <= 2500 &&
                   SERVO_PULSE_MIN_US < SERVO_PULSE_MAX_US,
               "servo pulse widths must lie in 500..2500 us, min below max");

/* ---- pure geometry and timing (host-tested) -------------------------------------------------- */

/* Timer1 ticks (0.5 µs) of the pulse for servo angle s (centidegrees, 0…18000): SERVO_PULSE_MIN_US
 * at 0°, SERVO_PULSE_MAX_US at 180°, linear, rounded; s is first clamped to the sweep limits. */
uint16_t servo_pulse_ticks(int32_t servo_cdeg);
/* The same for a head angle (servo angle − 90°). */
uint16_t servo_pulse_ticks_of_head(int32_t head_cdeg);
/* Head angle (centidegrees) of head position q (units of 0.75° from the lower limit). */
int32_t servo_cdeg_of_q(int16_t q);
/* Centre of reading i, centidegrees. */
int32_t servo_centre_cdeg(uint8_t i);
/* Position of ping j (in the order of motion) of reading i in a sweep of direction dir. */
int16_t servo_ping_q(uint8_t i, uint8_t j, int8_t dir);
/* Milliseconds to wait after commanding a move of delta_cdeg before pinging: the new pulse takes
 * effect at the next 20 ms PWM frame, the shaft turns at SERVO_MS_PER_60DEG, then rings out for
 * SERVO_RING_MS. */
uint16_t servo_settle_ms(uint32_t delta_cdeg);

/* ---- the head state machine (motion.h's interface) ------------------------------------------- */

typedef void (*head_emit_fn)(void *ctx, const dev_msg *m);

enum { HEAD_IDLE = 0, HEAD_SWEEP };
enum { HEAD_ACT_NONE = 0, HEAD_ACT_MOVE, HEAD_ACT_PING };

typedef struct {
    bool full;
    uint8_t first, last; /* reading indices of a local segment */
} head_scan;

typedef struct {
    head_emit_fn emit;
    void *ctx;
    const char *head_id; /* 16 hex digits, RAM */

    uint8_t activity; /* HEAD_IDLE or HEAD_SWEEP */
    head_scan scan;
    bool known;      /* the servo has been sent to q (else: anywhere in 0…180°) */
    int16_t q;       /* position last commanded, units of 0.75° from the lower limit */
    int8_t dir;      /* direction of the last move, +1 CCW (angle increasing), −1 CW */
    uint16_t settle; /* HEAD_ACT_MOVE: ms the caller waits before the next ping */

    uint32_t sweep; /* HEAD_SWEEP: its id */
    int8_t sdir;    /* HEAD_SWEEP: its direction */
    uint8_t k;      /* HEAD_SWEEP: reading in sweep order */
    uint8_t ping;   /* HEAD_SWEEP: next ping of that reading */
    bool ping_out;  /* a ping was asked for and its result is awaited */
    bool silent_reported;

    uint32_t last_sweep; /* latest sweep id started, 0 before the first */
    uint32_t seq;        /* RD counter */
    uint16_t echoes[HEAD_PINGS];
} head_t;

/* Power-on: idle, position unknown. Sends nothing. */
void head_init(head_t *h, const char *head_id, head_emit_fn emit, void *ctx);
/* The unprompted HELLO line (also the reply to HELLO,2): the servo's limits and step. */
void head_send_hello(head_t *h);
/* One command from the PC (already parsed). */
void head_command(head_t *h, const proto_cmd *cmd);
/* What to do next: HEAD_ACT_MOVE (send the servo to h->q, then wait h->settle ms before any
 * ping), HEAD_ACT_PING (a ping, then head_ping_done), or HEAD_ACT_NONE. Asking again without
 * acting asks for the ping again, never for a second move. */
uint8_t head_next(head_t *h);
/* The ping asked for finished: as motion.h. */
void head_ping_done(head_t *h, uint16_t echo_us, bool silent, uint32_t now_ms);
/* Whether a scan is under way (for the LED). */
bool head_busy(const head_t *h);
/* ST angle: the position last commanded (0, straight ahead, before the first). */
int32_t head_angle_cdeg(const head_t *h);

#endif
