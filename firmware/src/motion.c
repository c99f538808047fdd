/*
 * motion.c — see motion.h. No I/O, no timing: the host unit tests run this very file.
 */
#include "motion.h"

#include "compat.h"

#include <string.h>

/* The configured motor: MOTOR_NUM / MOTOR_DEN microsteps per output revolution (config.h). */
const motor_ratio MOTOR_RATIO = {MOTOR_NUM, MOTOR_DEN, LIMIT_SEEK_MICROSTEPS};

/* Integer-only position arithmetic in uint32 (the 28BYJ-48 is the largest case):
 * - motion_motor_of: q · NUM + 240 · DEN for q ≤ 402 (≈ 6.6e8 for the 28BYJ-48);
 * - motion_homing_limit: 380 · NUM;
 * - motion_cdeg_of_motor: |m| · 480 · DEN with |m| up to the homing travel (380°), ≈ 507 · NUM. */
_Static_assert((unsigned long long)(HEAD_MAX_UNITS + 2) * MOTOR_NUM + 240ULL * MOTOR_DEN < 0x100000000ULL,
               "q * MOTOR_NUM overflows 32 bits: use a smaller GEAR");
_Static_assert((unsigned long long)HOMING_MAX_DEG * MOTOR_NUM + 360ULL * MOTOR_DEN < 0x100000000ULL,
               "homing travel overflows 32 bits: use a smaller GEAR");
_Static_assert(((unsigned long long)HOMING_MAX_DEG * HEAD_UNITS_PER_REV / 360 + 2) * MOTOR_NUM +
                       (unsigned long long)HEAD_UNITS_PER_REV * MOTOR_DEN <
                   0x100000000ULL,
               "motor position to angle overflows 32 bits: use a smaller GEAR");
/* The creep past a limit (the switch tolerance and the rounding) is counted in a uint8_t. */
_Static_assert((unsigned long long)HEAD_SWITCH_TOLERANCE_UNITS * MOTOR_NUM /
                           ((unsigned long long)HEAD_UNITS_PER_REV * MOTOR_DEN) +
                       LIMIT_SEEK_MICROSTEPS + 1 <=
                   255,
               "the creep past a limit overflows 8 bits: use a smaller GEAR");
/* Motor positions are int32 and every head position has its own microstep. */
_Static_assert(MOTOR_NUM >= (unsigned long)HEAD_UNITS_PER_REV * MOTOR_DEN,
               "the motor must make at least one microstep per 0.75 degree");

/* ---- geometry -------------------------------------------------------------------------------- */

int32_t motion_motor_of(const motor_ratio *r, int16_t q)
{
    uint32_t den = (uint32_t)HEAD_UNITS_PER_REV * r->den;
    uint32_t mag = (uint32_t)(q < 0 ? -q : q);
    uint32_t steps = (mag * r->num + den / 2u) / den;
    return q < 0 ? -(int32_t)steps : (int32_t)steps;
}

int32_t motion_cdeg_of_motor(const motor_ratio *r, int32_t m)
{
    /* angle − min = m · (480 · DEN / NUM) units of 75 cdeg. Split m · 480 · DEN = a · NUM + b
     * so that only b · 75 < NUM · 75 needs to fit. */
    uint32_t mag = (uint32_t)(m < 0 ? -m : m);
    uint32_t x = mag * (uint32_t)HEAD_UNITS_PER_REV * r->den;
    uint32_t a = x / r->num;
    uint32_t b = x % r->num;
    uint32_t cdeg = a * (uint32_t)HEAD_UNIT_CDEG + (b * (uint32_t)HEAD_UNIT_CDEG + r->num / 2u) / r->num;
    return HEAD_MIN_CDEG + (m < 0 ? -(int32_t)cdeg : (int32_t)cdeg);
}

uint32_t motion_homing_limit(const motor_ratio *r)
{
    uint32_t den = 360u * r->den;
    return (HOMING_MAX_DEG * r->num + den - 1u) / den;
}

/* ULN2003 half-step sequence (phase 0..7): {IN1}, {IN1,IN2}, {IN2}, {IN2,IN3}, {IN3}, {IN3,IN4},
 * {IN4}, {IN4,IN1}; bit 0 = IN1 … bit 3 = IN4. Consecutive phases share one coil, so every step
 * is a half step of the 7.5° motor (3.75°), 0.75° at the head through the 1:5 gear. */
static const uint8_t HALFSTEP[8] PROGMEM = {0x1, 0x3, 0x2, 0x6, 0x4, 0xC, 0x8, 0x9};

uint8_t motion_halfstep_pattern(uint8_t phase)
{
    return (uint8_t)flash_char((const char *)&HALFSTEP[phase & 7u]);
}

int32_t motion_centre_cdeg(uint8_t i)
{
    /* Reading i covers [min + 6°·i, min + 6°·(i + 1)]; its centre is 3° in. */
    return HEAD_MIN_CDEG + (int32_t)HEAD_PINGS * HEAD_STEP_CDEG * (2 * (int32_t)i + 1) / 2;
}

int16_t motion_ping_q(uint8_t i, uint8_t j, int8_t dir)
{
    int16_t centre = (int16_t)(HEAD_PINGS * (2 * i + 1));
    return (int16_t)(centre + dir * (2 * j - (HEAD_PINGS - 1)));
}

void motion_segment_ends(uint8_t first, uint8_t last, int16_t *lo, int16_t *hi)
{
    *lo = (int16_t)(HEAD_PINGS * (2 * first + 1) - (HEAD_PINGS - 1));
    *hi = (int16_t)(HEAD_PINGS * (2 * last + 1) + (HEAD_PINGS - 1));
}

/* ---- the head state machine ------------------------------------------------------------------ */

static void emit(head_t *h, const dev_msg *m)
{
    h->emit(h->ctx, m);
}

static void send_ack(head_t *h, const char *tag_P)
{
    dev_msg m;
    m.kind = MSG_ACK;
    m.u.ack.tag_P = tag_P;
    emit(h, &m);
}

static void send_lim(head_t *h, uint8_t which)
{
    dev_msg m;
    m.kind = MSG_LIM;
    m.u.lim.which = which;
    emit(h, &m);
}

static void send_swp_end(head_t *h, uint32_t sweep)
{
    dev_msg m;
    m.kind = MSG_SWP_END;
    m.u.swp.sweep = sweep;
    emit(h, &m);
}

static void send_err_P(head_t *h, uint8_t code, const char *text_P)
{
    dev_msg m;
    proto_err_P(&m, code, text_P);
    emit(h, &m);
}

static void bounds(const head_t *h, uint8_t *lo, uint8_t *hi)
{
    if (h->scan.full) {
        *lo = 0;
        *hi = HEAD_READINGS - 1;
    } else {
        *lo = h->scan.first;
        *hi = h->scan.last;
    }
}

static void start_homing(head_t *h)
{
    h->activity = HEAD_HOMING;
    h->homed = false;
    h->moving = false;
    h->seek_left = 0;
    h->seek_exhausted = false;
    h->ping_out = false;
    h->pending = false;
    /* Where the head is, nobody knows: assume the far end (+150°), so the count reaches −150°
     * after 300° of travel, the longest way home. ST reports this assumed angle. */
    h->q = HEAD_MAX_UNITS;
    h->m = motion_motor_of(h->ratio, HEAD_MAX_UNITS);
    h->dir = -1;
    h->home_travel = 0;
    h->home_phase = HOME_SEEK;
}

void head_init(head_t *h, const motor_ratio *r, const char *head_id, head_emit_fn fn, void *ctx)
{
    memset(h, 0, sizeof *h);
    h->ratio = r;
    h->emit = fn;
    h->ctx = ctx;
    h->head_id = head_id;
    h->home_limit = motion_homing_limit(r);
    h->scan.full = true;
    start_homing(h);
}

void head_send_hello(head_t *h)
{
    dev_msg m;
    m.kind = MSG_HELLO;
    m.u.hello.firmware_P = FSTR(FIRMWARE_NAME);
    m.u.hello.head_id = h->head_id;
    m.u.hello.step_cdeg = HEAD_STEP_CDEG;
    m.u.hello.pings = HEAD_PINGS;
    m.u.hello.min_cdeg = HEAD_MIN_CDEG;
    m.u.hello.max_cdeg = HEAD_MAX_CDEG;
    emit(h, &m);
}

/* Reports the end of a sweep still under way (a new command interrupts it). */
static void close_sweep(head_t *h)
{
    if (h->activity == HEAD_SWEEP) {
        send_swp_end(h, h->sweep);
    } else if (h->activity == HEAD_TRAVEL && h->ending != 0) {
        send_swp_end(h, h->ending);
        h->ending = 0;
    }
}

static void send_status(head_t *h);

/* A hardware fault: stop at once, say why (m: an ERR,HARDWARE message), end the open sweep, report
 * ST,FAULT. Only RESET moves the head again. */
static void fault(head_t *h, const dev_msg *m)
{
    uint32_t open = 0;
    if (h->activity == HEAD_SWEEP) {
        open = h->sweep;
    } else if (h->activity == HEAD_TRAVEL) {
        open = h->ending;
    }
    h->activity = HEAD_FAULT;
    h->moving = false;
    h->seek_left = 0;
    h->seek_exhausted = false;
    h->pending = false;
    h->ping_out = false;
    h->ending = 0;
    memcpy(h->fault_text, m->u.err.text, sizeof h->fault_text);
    emit(h, m);
    if (open != 0) {
        send_swp_end(h, open);
    }
    send_status(h);
}

static void fault_P(head_t *h, const char *text_P)
{
    dev_msg m;
    proto_err_P(&m, ERR_HARDWARE, text_P);
    fault(h, &m);
}

/* A scan while stopped on a fault: the fault's ERR,HARDWARE line again, and no motion. */
static void refuse_scan(head_t *h)
{
    dev_msg m;
    m.kind = MSG_ERR;
    m.u.err.code = ERR_HARDWARE;
    memcpy(m.u.err.text, h->fault_text, sizeof m.u.err.text);
    emit(h, &m);
}

static void travel(head_t *h, head_scan scan)
{
    h->activity = HEAD_TRAVEL;
    h->scan = scan;
    h->planned = false; /* the target is chosen once any move under way has ended */
    h->ending = 0;
}

static void begin_scan(head_t *h, head_scan scan)
{
    h->ping_out = false;
    if (h->activity == HEAD_HOMING) {
        h->pending = true; /* starts when homing ends */
        h->pending_scan = scan;
        return;
    }
    close_sweep(h);
    travel(h, scan);
}

static void send_status(head_t *h)
{
    dev_msg m;
    m.kind = MSG_ST;
    switch (h->activity) {
    case HEAD_HOMING:
        m.u.st.state = STATE_HOMING;
        break;
    case HEAD_FAULT:
        m.u.st.state = STATE_FAULT;
        break;
    case HEAD_TRAVEL:
    case HEAD_SWEEP:
        m.u.st.state = h->scan.full ? STATE_FULL : STATE_LOCAL;
        break;
    default:
        m.u.st.state = STATE_IDLE;
        break;
    }
    m.u.st.angle_cdeg = head_angle_cdeg(h);
    m.u.st.dir = h->dir;
    m.u.st.sweep = h->activity == HEAD_SWEEP ? h->sweep : h->last_sweep;
    emit(h, &m);
}

void head_command(head_t *h, const proto_cmd *cmd)
{
    switch (cmd->kind) {
    case CMD_HELLO:
        if (cmd->version == PROTO_VERSION) {
            head_send_hello(h);
        } else {
            dev_msg m;
            proto_version_err(&m, cmd->version);
            emit(h, &m);
        }
        break;
    case CMD_SCAN_FULL: {
        if (h->activity == HEAD_FAULT) {
            refuse_scan(h);
            break;
        }
        send_ack(h, FSTR("SCAN"));
        head_scan scan = {true, 0, HEAD_READINGS - 1};
        begin_scan(h, scan);
        break;
    }
    case CMD_SCAN_LOCAL: {
        if (h->activity == HEAD_FAULT) {
            refuse_scan(h);
            break;
        }
        int16_t first = -1, last = -1;
        for (uint8_t i = 0; i < HEAD_READINGS; i++) {
            int32_t c = motion_centre_cdeg(i);
            if (c >= cmd->from_cdeg && c <= cmd->to_cdeg) {
                if (first < 0) {
                    first = (int16_t)i;
                }
                last = (int16_t)i;
            }
        }
        if (first < 0 || cmd->from_cdeg < HEAD_MIN_CDEG || cmd->to_cdeg > HEAD_MAX_CDEG) {
            dev_msg m;
            proto_range_err(&m, first < 0, cmd->from_cdeg, cmd->to_cdeg, HEAD_MIN_CDEG, HEAD_MAX_CDEG);
            emit(h, &m);
            break;
        }
        send_ack(h, FSTR("SCAN"));
        head_scan scan = {false, (uint8_t)first, (uint8_t)last};
        begin_scan(h, scan);
        break;
    }
    case CMD_STOP:
        send_ack(h, FSTR("STOP"));
        h->ping_out = false; /* the ping under way ends, its result is dropped */
        if (h->activity == HEAD_HOMING) {
            /* Homing runs on (the head must learn where it is); only the waiting scan is dropped. */
            h->pending = false;
        } else if (h->activity != HEAD_FAULT) { /* a fault stays until RESET */
            close_sweep(h);
            h->activity = HEAD_IDLE;
        }
        break;
    case CMD_RESET:
        /* A person has looked at the head: clear the fault and home again (from anywhere: the
         * position is not trusted after a fault). */
        send_ack(h, FSTR("RESET"));
        close_sweep(h);
        start_homing(h);
        break;
    case CMD_STATUS:
    default:
        send_status(h);
        break;
    }
}

/* Begins a move of at most one 1.5° step (two units) toward target, like the Rust model's
 * step_toward: commands are obeyed between such moves. */
static void start_move(head_t *h, int16_t target)
{
    int16_t delta = (int16_t)(target - h->q);
    if (delta > 2) {
        delta = 2;
    } else if (delta < -2) {
        delta = -2;
    }
    h->move_to = (int16_t)(h->q + delta);
    h->moving = true;
    h->dir = delta > 0 ? 1 : -1;
}

static void plan(head_t *h)
{
    if (h->scan.full) {
        bool at_limit = h->q == 0 || h->q == HEAD_MAX_UNITS;
        h->target = at_limit ? h->q : (h->dir > 0 ? HEAD_MAX_UNITS : 0);
    } else {
        int16_t lo, hi;
        motion_segment_ends(h->scan.first, h->scan.last, &lo, &hi);
        int16_t dlo = (int16_t)(h->q > lo ? h->q - lo : lo - h->q);
        int16_t dhi = (int16_t)(h->q > hi ? h->q - hi : hi - h->q);
        h->target = dlo <= dhi ? lo : hi;
    }
    h->planned = true;
}

/* Begins a sweep from where the head stands (a limit, or an end of the local segment). */
static void start_sweep(head_t *h)
{
    uint8_t lo, hi;
    bounds(h, &lo, &hi);
    if (h->scan.full) {
        h->sdir = h->q == 0 ? 1 : -1;
    } else {
        int16_t lo_q, hi_q;
        motion_segment_ends(lo, hi, &lo_q, &hi_q);
        h->sdir = h->q <= lo_q ? 1 : -1;
    }
    h->dir = h->sdir;
    h->last_sweep++;
    dev_msg m;
    m.kind = MSG_SWP_START;
    m.u.swp.sweep = h->last_sweep;
    m.u.swp.dir = h->sdir;
    m.u.swp.full = h->scan.full;
    m.u.swp.from_cdeg = motion_centre_cdeg(h->sdir > 0 ? lo : hi);
    m.u.swp.to_cdeg = motion_centre_cdeg(h->sdir > 0 ? hi : lo);
    emit(h, &m);
    h->activity = HEAD_SWEEP;
    h->sweep = h->last_sweep;
    h->k = 0;
    h->ping = 0;
    h->ping_out = false;
    h->silent_reported = false;
}

static uint8_t current_reading(const head_t *h)
{
    uint8_t lo, hi;
    bounds(h, &lo, &hi);
    return (uint8_t)(h->sdir > 0 ? lo + h->k : hi - h->k);
}

uint8_t head_next(head_t *h)
{
    for (;;) {
        if (h->moving) {
            int32_t goal = motion_motor_of(h->ratio, h->move_to);
            if (h->m != goal) {
                h->step_dir = h->m < goal ? 1 : -1;
                return HEAD_ACT_STEP;
            }
            h->moving = false;
            h->q = h->move_to;
            if (h->q == 0 || h->q == HEAD_MAX_UNITS) {
                /* At the sweep limit and its switch has not closed (else head_check_switches
                 * would have ended the move): creep on by the tolerance (and what the motor's
                 * rounding needs) to meet it. */
                h->seek_left = (uint8_t)(motion_motor_of(h->ratio, HEAD_SWITCH_TOLERANCE_UNITS) +
                                         h->ratio->limit_seek);
            }
        }
        if (h->seek_exhausted) {
            /* Crept on as far as allowed: the switch is dead, or steps were missed. */
            dev_msg m;
            tbuf t;
            m.kind = MSG_ERR;
            m.u.err.code = ERR_HARDWARE;
            tb_init(&t, m.u.err.text, PROTO_TEXT_MAX);
            tb_str_P(&t, h->dir < 0 ? FSTR("MIN") : FSTR("MAX"));
            tb_str_P(&t, FSTR(" switch open at "));
            tb_i32(&t, motion_cdeg_of_motor(h->ratio, h->m));
            tb_str_P(&t, FSTR(" cdeg past its limit (dead switch? missed steps?)"));
            fault(h, &m);
            return HEAD_ACT_NONE;
        }
        if (h->seek_left != 0) {
            h->step_dir = h->dir;
            return HEAD_ACT_STEP;
        }
        switch (h->activity) {
        case HEAD_HOMING:
            if (h->home_phase == HOME_LEAVE &&
                h->home_travel >= (uint32_t)motion_motor_of(h->ratio, HOME_LEAVE_MAX_UNITS)) {
                fault_P(h, FSTR("MIN switch stuck closed (still closed 30 deg off it)"));
                return HEAD_ACT_NONE;
            }
            if (h->home_travel >= h->home_limit) {
                dev_msg m;
                tbuf t;
                m.kind = MSG_ERR;
                m.u.err.code = ERR_HARDWARE;
                tb_init(&t, m.u.err.text, PROTO_TEXT_MAX);
                tb_str_P(&t, FSTR("MIN switch not found in "));
                tb_u32(&t, HOMING_MAX_DEG);
                tb_str_P(&t, FSTR(" deg of homing (dead switch? wiring?)"));
                fault(h, &m);
                return HEAD_ACT_NONE;
            }
            if (h->home_phase == HOME_CLEAR && h->home_clear_left == 0) {
                h->home_phase = HOME_SEEK;
            }
            h->dir = h->home_phase == HOME_SEEK ? -1 : 1;
            h->step_dir = h->dir;
            return HEAD_ACT_STEP;
        case HEAD_TRAVEL:
            if (!h->planned) {
                plan(h);
            }
            if (h->q != h->target) {
                start_move(h, h->target);
                continue;
            }
            if (h->ending != 0) {
                send_swp_end(h, h->ending);
                h->ending = 0;
            }
            start_sweep(h);
            continue;
        case HEAD_SWEEP: {
            int16_t t = motion_ping_q(current_reading(h), h->ping, h->sdir);
            if (h->q != t) {
                start_move(h, t);
                continue;
            }
            h->ping_out = true;
            return HEAD_ACT_PING;
        }
        case HEAD_IDLE:
        case HEAD_FAULT:
        default:
            return HEAD_ACT_NONE;
        }
    }
}

void head_stepped(head_t *h)
{
    h->m += h->step_dir;
    if (h->activity == HEAD_HOMING) {
        h->home_travel++;
        if (h->home_phase == HOME_CLEAR && h->home_clear_left != 0) {
            h->home_clear_left--;
        }
    }
    if (h->seek_left != 0 && --h->seek_left == 0) {
        /* Crept on as far as allowed. A switch closing on this very microstep is still seen by
         * head_check_switches; if it does not, head_next stops the head. */
        h->seek_exhausted = true;
    }
}

/* ERR,HARDWARE for a switch that closed too far before its limit. */
static void early_switch(head_t *h, bool min)
{
    int32_t at = motion_cdeg_of_motor(h->ratio, h->m);
    int32_t early = min ? at - HEAD_MIN_CDEG : HEAD_MAX_CDEG - at;
    dev_msg m;
    tbuf t;
    m.kind = MSG_ERR;
    m.u.err.code = ERR_HARDWARE;
    tb_init(&t, m.u.err.text, PROTO_TEXT_MAX);
    tb_str_P(&t, min ? FSTR("MIN") : FSTR("MAX"));
    tb_str_P(&t, FSTR(" switch closed at "));
    tb_i32(&t, at);
    tb_str_P(&t, FSTR(" cdeg: "));
    tb_i32(&t, early);
    tb_str_P(&t, FSTR(" cdeg early (switch moved? missed steps?)"));
    fault(h, &m);
}

bool head_check_switches(head_t *h, uint8_t closed, int8_t dir)
{
    if (h->activity == HEAD_FAULT) {
        return true; /* nothing moves */
    }
    if ((closed & (HEAD_SW_MIN | HEAD_SW_MAX)) == (HEAD_SW_MIN | HEAD_SW_MAX)) {
        /* The head cannot be at both ends: one is stuck closed or the wiring is shorted. */
        fault_P(h, FSTR("both limit switches closed (one stuck? wiring shorted?)"));
        return true;
    }
    if (dir == 0) {
        return false;
    }
    if (h->activity == HEAD_HOMING) {
        if (dir > 0) {
            if (closed & HEAD_SW_MAX) {
                /* Leaving the MIN switch ran into MAX: the MIN switch is stuck closed. */
                fault_P(h, FSTR("MAX switch closed while homing (MIN switch stuck closed?)"));
                return true;
            }
            if (h->home_phase == HOME_LEAVE && !(closed & HEAD_SW_MIN)) {
                /* Off the switch: a little further so its bounce is behind us, then back onto it. */
                h->home_phase = HOME_CLEAR;
                h->home_clear_left = (uint32_t)motion_motor_of(h->ratio, HOME_CLEAR_UNITS);
            }
            return false;
        }
        if (!(closed & HEAD_SW_MIN)) {
            return false;
        }
        if (h->home_phase == HOME_SEEK && h->home_travel == 0) {
            /* Closed before any step: at the switch or beyond it. Leave it first. */
            h->home_phase = HOME_LEAVE;
            h->dir = 1;
            h->step_dir = 1;
            return true;
        }
        h->homed = true;
        h->moving = false;
        h->q = 0;
        h->m = 0;
        h->dir = 1; /* the switch reversed the motor */
        h->activity = HEAD_IDLE;
        send_lim(h, LIMIT_MIN);
        if (h->pending) {
            h->pending = false;
            travel(h, h->pending_scan);
        }
        return true;
    }
    if (!(closed & (dir < 0 ? HEAD_SW_MIN : HEAD_SW_MAX))) {
        return false; /* a switch behind the motion (leaving it, bouncing) is ignored */
    }
    bool min = dir < 0;
    int16_t limit = min ? 0 : HEAD_MAX_UNITS;
    bool early = min ? h->m > motion_motor_of(h->ratio, HEAD_SWITCH_TOLERANCE_UNITS)
                     : h->m < motion_motor_of(h->ratio, HEAD_MAX_UNITS - HEAD_SWITCH_TOLERANCE_UNITS);
    if (early) {
        /* Far from where the step count puts it: either the switch or the count is wrong, and
         * nothing tells which. Stop rather than trust either. */
        early_switch(h, min);
        return true;
    }
    send_lim(h, min ? LIMIT_MIN : LIMIT_MAX);
    h->moving = false;
    h->seek_left = 0;
    h->seek_exhausted = false;
    h->q = limit;
    h->m = motion_motor_of(h->ratio, limit);
    h->dir = min ? 1 : -1;
    if (h->activity == HEAD_SWEEP) {
        /* The switch ends the sweep (the reading under way is dropped); the next one starts
         * back from the limit. */
        send_swp_end(h, h->sweep);
        start_sweep(h);
    } else if (h->activity == HEAD_TRAVEL && h->ending == 0) {
        /* A travel to a scan's start chooses its target again from the limit (a run-on to this
         * very switch has arrived). */
        h->planned = false;
    }
    return true;
}

void head_ping_done(head_t *h, uint16_t echo_us, bool silent, uint32_t now_ms)
{
    if (!h->ping_out || h->activity != HEAD_SWEEP) {
        return;
    }
    h->ping_out = false;
    if (silent && !h->silent_reported) {
        h->silent_reported = true;
        send_err_P(h, ERR_HARDWARE, FSTR("sensor silent"));
    }
    h->echoes[h->ping] = echo_us;
    if (h->ping + 1 < HEAD_PINGS) {
        h->ping++;
        return;
    }
    uint8_t reading = current_reading(h);
    dev_msg m;
    m.kind = MSG_RD;
    m.u.rd.seq = h->seq;
    m.u.rd.time_ms = now_ms;
    m.u.rd.sweep = h->sweep;
    m.u.rd.dir = h->sdir;
    m.u.rd.angle_cdeg = motion_centre_cdeg(reading);
    m.u.rd.n = HEAD_PINGS;
    m.u.rd.echo_us = h->echoes;
    emit(h, &m);
    h->seq++;
    uint8_t lo, hi;
    bounds(h, &lo, &hi);
    if (h->k < hi - lo) {
        h->k++;
        h->ping = 0;
    } else if (h->scan.full) {
        /* Run on to the limit switch, which ends the sweep. */
        h->activity = HEAD_TRAVEL;
        h->planned = true;
        h->target = h->sdir > 0 ? HEAD_MAX_UNITS : 0;
        h->ending = h->sweep;
    } else {
        send_swp_end(h, h->sweep);
        start_sweep(h);
    }
}

bool head_busy(const head_t *h)
{
    return h->activity != HEAD_IDLE;
}

int32_t head_angle_cdeg(const head_t *h)
{
    int32_t a = motion_cdeg_of_motor(h->ratio, h->m);
    if (a < HEAD_MIN_CDEG) {
        return HEAD_MIN_CDEG;
    }
    if (a > HEAD_MAX_CDEG) {
        return HEAD_MAX_CDEG;
    }
    return a;
}
