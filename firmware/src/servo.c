/*
 * servo.c — see servo.h. No I/O, no timing: the host unit tests run this very file.
 */
#include "servo.h"

#include "compat.h"

#include <string.h>

/* ---- geometry and timing --------------------------------------------------------------------- */

uint16_t servo_pulse_ticks(int32_t servo_cdeg)
{
    /* Never beyond the sweep limits, whatever the caller asks: the horn stays inside its travel. */
    if (servo_cdeg < (int32_t)SERVO_MIN_DEG * 100) {
        servo_cdeg = (int32_t)SERVO_MIN_DEG * 100;
    } else if (servo_cdeg > (int32_t)SERVO_MAX_DEG * 100) {
        servo_cdeg = (int32_t)SERVO_MAX_DEG * 100;
    }
    /* Timer1 counts 0.5 µs: 2 ticks per µs. (2 · 2000 · 18000 fits 32 bits.) */
    uint32_t span = 2UL * (SERVO_PULSE_MAX_US - SERVO_PULSE_MIN_US);
    return (uint16_t)(2UL * SERVO_PULSE_MIN_US + (span * (uint32_t)servo_cdeg + 9000UL) / 18000UL);
}

uint16_t servo_pulse_ticks_of_head(int32_t head_cdeg)
{
    return servo_pulse_ticks(head_cdeg + 9000);
}

int32_t servo_cdeg_of_q(int16_t q)
{
    return SERVO_HEAD_MIN_CDEG + (int32_t)q * HEAD_UNIT_CDEG;
}

int32_t servo_centre_cdeg(uint8_t i)
{
    return servo_cdeg_of_q((int16_t)(HEAD_PINGS * (2 * i + 1)));
}

int16_t servo_ping_q(uint8_t i, uint8_t j, int8_t dir)
{
    int16_t centre = (int16_t)(HEAD_PINGS * (2 * i + 1));
    return (int16_t)(centre + dir * (2 * j - (HEAD_PINGS - 1)));
}

uint16_t servo_settle_ms(uint32_t delta_cdeg)
{
    uint32_t turn = (delta_cdeg * SERVO_MS_PER_60DEG + 5999UL) / 6000UL; /* rounded up */
    return (uint16_t)(SERVO_PERIOD_US / 1000UL + turn + SERVO_RING_MS);
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

static void send_swp_end(head_t *h)
{
    dev_msg m;
    m.kind = MSG_SWP_END;
    m.u.swp.sweep = h->sweep;
    emit(h, &m);
}

static void bounds(const head_t *h, uint8_t *lo, uint8_t *hi)
{
    if (h->scan.full) {
        *lo = 0;
        *hi = SERVO_READINGS - 1;
    } else {
        *lo = h->scan.first;
        *hi = h->scan.last;
    }
}

void head_init(head_t *h, const char *head_id, head_emit_fn fn, void *ctx)
{
    memset(h, 0, sizeof *h);
    h->emit = fn;
    h->ctx = ctx;
    h->head_id = head_id;
    h->dir = 1;
    h->scan.full = true;
}

void head_send_hello(head_t *h)
{
    dev_msg m;
    m.kind = MSG_HELLO;
    m.u.hello.firmware_P = FSTR(FIRMWARE_NAME);
    m.u.hello.head_id = h->head_id;
    m.u.hello.step_cdeg = HEAD_STEP_CDEG;
    m.u.hello.pings = HEAD_PINGS;
    m.u.hello.min_cdeg = SERVO_HEAD_MIN_CDEG;
    m.u.hello.max_cdeg = SERVO_HEAD_MAX_CDEG;
    emit(h, &m);
}

/* Begins a sweep of the scan's readings from the end nearer to the servo (the lower end when its
 * position is unknown), or, after a sweep, back from where it ended. */
static void start_sweep(head_t *h, int8_t sdir)
{
    uint8_t lo, hi;
    bounds(h, &lo, &hi);
    h->sdir = sdir;
    h->last_sweep++;
    h->sweep = h->last_sweep;
    h->activity = HEAD_SWEEP;
    h->k = 0;
    h->ping = 0;
    h->ping_out = false;
    h->silent_reported = false;
    dev_msg m;
    m.kind = MSG_SWP_START;
    m.u.swp.sweep = h->sweep;
    m.u.swp.dir = sdir;
    m.u.swp.full = h->scan.full;
    m.u.swp.from_cdeg = servo_centre_cdeg(sdir > 0 ? lo : hi);
    m.u.swp.to_cdeg = servo_centre_cdeg(sdir > 0 ? hi : lo);
    emit(h, &m);
}

static void begin_scan(head_t *h, head_scan scan)
{
    if (h->activity == HEAD_SWEEP) {
        send_swp_end(h);
    }
    h->scan = scan;
    uint8_t lo, hi;
    bounds(h, &lo, &hi);
    int16_t lo_q = servo_ping_q(lo, 0, 1);
    int16_t hi_q = servo_ping_q(hi, 0, -1);
    bool from_hi = h->known && (h->q > hi_q || (h->q > lo_q && hi_q - h->q < h->q - lo_q));
    start_sweep(h, from_hi ? -1 : 1);
}

static void send_status(head_t *h)
{
    dev_msg m;
    m.kind = MSG_ST;
    m.u.st.state = h->activity == HEAD_SWEEP ? (h->scan.full ? STATE_FULL : STATE_LOCAL) : STATE_IDLE;
    m.u.st.angle_cdeg = head_angle_cdeg(h);
    m.u.st.dir = h->dir;
    m.u.st.sweep = h->last_sweep;
    emit(h, &m);
}

static void stop(head_t *h)
{
    h->ping_out = false; /* the ping under way ends, its result is dropped */
    if (h->activity == HEAD_SWEEP) {
        send_swp_end(h);
    }
    h->activity = HEAD_IDLE;
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
        send_ack(h, FSTR("SCAN"));
        head_scan scan = {true, 0, SERVO_READINGS - 1};
        begin_scan(h, scan);
        break;
    }
    case CMD_SCAN_LOCAL: {
        int16_t first = -1, last = -1;
        for (uint8_t i = 0; i < SERVO_READINGS; i++) {
            int32_t c = servo_centre_cdeg(i);
            if (c >= cmd->from_cdeg && c <= cmd->to_cdeg) {
                if (first < 0) {
                    first = (int16_t)i;
                }
                last = (int16_t)i;
            }
        }
        if (first < 0 || cmd->from_cdeg < SERVO_HEAD_MIN_CDEG || cmd->to_cdeg > SERVO_HEAD_MAX_CDEG) {
            dev_msg m;
            proto_range_err(&m, first < 0, cmd->from_cdeg, cmd->to_cdeg, SERVO_HEAD_MIN_CDEG,
                            SERVO_HEAD_MAX_CDEG);
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
        stop(h);
        break;
    case CMD_RESET:
        /* Nothing to home and no fault to clear: the scan ends, the servo stays where it is. */
        send_ack(h, FSTR("RESET"));
        stop(h);
        break;
    case CMD_STATUS:
    default:
        send_status(h);
        break;
    }
}

uint8_t head_next(head_t *h)
{
    if (h->activity != HEAD_SWEEP) {
        return HEAD_ACT_NONE;
    }
    uint8_t lo, hi;
    bounds(h, &lo, &hi);
    uint8_t reading = (uint8_t)(h->sdir > 0 ? lo + h->k : hi - h->k);
    int16_t target = servo_ping_q(reading, h->ping, h->sdir);
    if (!h->known || h->q != target) {
        /* From an unknown position the servo may have to turn all of its 180°. */
        uint32_t delta = h->known ? (uint32_t)(target > h->q ? target - h->q : h->q - target) *
                                        HEAD_UNIT_CDEG
                                  : 18000UL;
        h->settle = servo_settle_ms(delta);
        if (h->known && target != h->q) {
            h->dir = target > h->q ? 1 : -1;
        }
        h->q = target;
        h->known = true;
        return HEAD_ACT_MOVE;
    }
    h->ping_out = true;
    return HEAD_ACT_PING;
}

void head_ping_done(head_t *h, uint16_t echo_us, bool silent, uint32_t now_ms)
{
    if (!h->ping_out || h->activity != HEAD_SWEEP) {
        return;
    }
    h->ping_out = false;
    if (silent && !h->silent_reported) {
        h->silent_reported = true;
        dev_msg m;
        proto_err_P(&m, ERR_HARDWARE, FSTR("sensor silent"));
        emit(h, &m);
    }
    h->echoes[h->ping] = echo_us;
    if (h->ping + 1 < HEAD_PINGS) {
        h->ping++;
        return;
    }
    uint8_t lo, hi;
    bounds(h, &lo, &hi);
    uint8_t reading = (uint8_t)(h->sdir > 0 ? lo + h->k : hi - h->k);
    dev_msg m;
    m.kind = MSG_RD;
    m.u.rd.seq = h->seq;
    m.u.rd.time_ms = now_ms;
    m.u.rd.sweep = h->sweep;
    m.u.rd.dir = h->sdir;
    m.u.rd.angle_cdeg = servo_centre_cdeg(reading);
    m.u.rd.n = HEAD_PINGS;
    m.u.rd.echo_us = h->echoes;
    emit(h, &m);
    h->seq++;
    if (h->k < hi - lo) {
        h->k++;
        h->ping = 0;
    } else {
        /* The last reading: the sweep ends here and the next one comes back over the same ones. */
        send_swp_end(h);
        start_sweep(h, (int8_t)-h->sdir);
    }
}

bool head_busy(const head_t *h)
{
    return h->activity != HEAD_IDLE;
}

int32_t head_angle_cdeg(const head_t *h)
{
    return h->known ? servo_cdeg_of_q(h->q) : 0;
}
