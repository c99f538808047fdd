/*
 * Geometry tests: the half-step sequence, position → motor step rounding for the three motors,
 * angles from motor positions, reading centres and ping positions.
 */
#include "motion.h"
#include "tinytest.h"

#include <stdlib.h>

static const motor_ratio PAPER = {96UL * 5, 1, 0};      /* 7.5° motor half-stepped, 1:5 gear */
static const motor_ratio BYJ48 = {1650688UL, 405, 2};   /* 28BYJ-48 half-stepped */
static const motor_ratio NEMA17 = {3200UL, 1, 2};       /* 1.8° at 1/16 microstep */
static const motor_ratio *const MOTORS[3] = {&PAPER, &BYJ48, &NEMA17};

static void halfstep_sequence(void)
{
    enum { IN1 = 1, IN2 = 2, IN3 = 4, IN4 = 8 };
    const uint8_t expect[8] = {IN1, IN1 | IN2, IN2, IN2 | IN3, IN3, IN3 | IN4, IN4, IN4 | IN1};
    for (uint8_t p = 0; p < 8; p++) {
        CHECK_INT(motion_halfstep_pattern(p), expect[p]);
        CHECK_INT(motion_halfstep_pattern((uint8_t)(p + 8)), expect[p]);
    }
}

static void halfstep_sequence_direction(void)
{
    /* Going up the phases (counter-clockwise, angle increasing) the energised coils rotate
     * IN1 → IN2 → IN3 → IN4: each half step switches exactly one coil on or off and keeps one
     * coil of the previous phase. Going down reverses that order. */
    for (uint8_t p = 0; p < 8; p++) {
        uint8_t a = motion_halfstep_pattern(p), b = motion_halfstep_pattern((uint8_t)(p + 1));
        uint8_t changed = (uint8_t)(a ^ b);
        CHECK(changed == 1 || changed == 2 || changed == 4 || changed == 8);
        CHECK((a & b) != 0);
    }
    /* The centre of the energised coils advances by half a coil per phase. */
    int centre_prev = -1;
    for (uint8_t p = 0; p < 8; p++) {
        uint8_t pat = motion_halfstep_pattern(p);
        int sum = 0, n = 0;
        for (int coil = 0; coil < 4; coil++) {
            if (pat & (1 << coil)) {
                /* IN4 next to IN1 (phase 7 = {IN4, IN1}): count IN1 as coil 4 there. */
                int pos = (coil == 0 && (pat & 8)) ? 8 : 2 * coil;
                sum += pos;
                n++;
            }
        }
        int centre = sum / n;
        CHECK_INT(centre, p);
        CHECK(centre > centre_prev);
        centre_prev = centre;
    }
}

static void paper_motor_is_exact(void)
{
    for (int16_t q = 0; q <= HEAD_MAX_UNITS; q++) {
        CHECK_INT(motion_motor_of(&PAPER, q), q);
        CHECK_INT(motion_cdeg_of_motor(&PAPER, q), -15000 + 75 * q);
    }
    CHECK_INT(motion_cdeg_of_motor(&PAPER, -4), -15300);
    CHECK_INT(motion_homing_limit(&PAPER), 420); /* 315° = one sweep + 15°, 420 half steps */
}

static void motor_rounding_over_the_sweep(void)
{
    for (int k = 0; k < 3; k++) {
        const motor_ratio *r = MOTORS[k];
        int64_t den = 480LL * r->den;
        int32_t prev = -1;
        int32_t min_move = INT32_MAX, max_move = 0;
        for (int16_t q = 0; q <= HEAD_MAX_UNITS; q++) {
            int32_t m = motion_motor_of(r, q);
            /* |m − q·NUM/(480·DEN)| ≤ ½ microstep, in integers: |2·m·den − 2·q·num| ≤ den. */
            int64_t err2 = 2 * (int64_t)m * den - 2 * (int64_t)q * r->num;
            if (llabs(err2) > den) {
                TT_FAIL("motor %d q %d: m %d off by more than half a microstep", k, q, m);
            }
            if (q > 0 && m <= prev) {
                TT_FAIL("motor %d q %d: not strictly increasing", k, q);
            }
            if (q >= 2 && q % 2 == 0) {
                int32_t move = m - motion_motor_of(r, (int16_t)(q - 2));
                if (move < min_move) {
                    min_move = move;
                }
                if (move > max_move) {
                    max_move = move;
                }
            }
            prev = m;
            /* The angle reported from the motor position is within half a microstep. */
            int32_t cdeg = motion_cdeg_of_motor(r, m);
            int64_t half_step_cdeg2 = (36000LL * r->den + r->num - 1) / r->num; /* 2 × ½ step */
            if (llabs(2LL * (cdeg - (-15000 + 75 * q))) > half_step_cdeg2 + 2) {
                TT_FAIL("motor %d q %d: angle %d", k, q, cdeg);
            }
            /* Symmetric for negative positions (homing from the assumed start). */
            CHECK_INT(motion_motor_of(r, (int16_t)-q), -m);
        }
        /* No drift: the whole sweep is exactly the rounded fraction. */
        int64_t exact2 = 2LL * HEAD_MAX_UNITS * r->num;
        CHECK(llabs(2LL * motion_motor_of(r, HEAD_MAX_UNITS) * den - exact2) <= den);
        /* Every 1.5° step has the floor or the ceiling of its exact microstep count. */
        CHECK(max_move - min_move <= 1);
        if (k == 1) {
            CHECK_INT(min_move, 16); /* 16.98 per 1.5° */
            CHECK_INT(max_move, 17);
            CHECK_INT(motion_motor_of(r, HEAD_MAX_UNITS), 3396); /* 300° = 3396.48 */
        }
        if (k == 2) {
            CHECK_INT(min_move, 13); /* 13.33 per 1.5° */
            CHECK_INT(max_move, 14);
            CHECK_INT(motion_motor_of(r, HEAD_MAX_UNITS), 2667);
        }
    }
}

static void motor_rounding_28byj48_no_drift_over_many_sweeps(void)
{
    /* Positions are absolute: after 1000 sweeps of 2-unit moves the motor is where a single
     * rounding puts it. */
    int32_t m = 0;
    int16_t q = 0;
    for (int sweep = 0; sweep < 1000; sweep++) {
        int dir = sweep % 2 == 0 ? 2 : -2;
        for (int i = 0; i < HEAD_MAX_UNITS / 2; i++) {
            int32_t from = motion_motor_of(&BYJ48, q);
            q = (int16_t)(q + dir);
            m += motion_motor_of(&BYJ48, q) - from;
        }
        CHECK_INT(m, motion_motor_of(&BYJ48, q));
    }
    CHECK_INT(q, 0);
    CHECK_INT(m, 0);
}

static void angles_over_the_homing_range(void)
{
    /* While homing, the motor position runs from the assumed +150° down through 380° of travel:
     * the angle arithmetic must hold there too (no 32-bit overflow), rounded to the centidegree. */
    for (int k = 0; k < 3; k++) {
        const motor_ratio *r = MOTORS[k];
        int32_t top = motion_motor_of(r, HEAD_MAX_UNITS);
        int32_t bottom = top - (int32_t)motion_homing_limit(r);
        for (int32_t m = bottom; m <= top; m++) {
            double exact = -15000.0 + (double)m * 36000.0 * r->den / r->num;
            double got = motion_cdeg_of_motor(r, m);
            if (got - exact > 0.5 || exact - got > 0.5) {
                TT_FAIL("motor %d m %d: %g vs %g", k, m, got, exact);
                break;
            }
        }
    }
}

static void homing_limits(void)
{
    CHECK_INT(motion_homing_limit(&BYJ48), 3567);  /* 315/360 × 4075.8 = 3566.3 */
    CHECK_INT(motion_homing_limit(&NEMA17), 2800); /* 315/360 × 3200 */
}

static void reading_centres(void)
{
    CHECK_INT(HEAD_READINGS, 50);
    for (uint8_t i = 0; i < HEAD_READINGS; i++) {
        CHECK_INT(motion_centre_cdeg(i), -14700 + 600 * i);
    }
    CHECK_INT(motion_centre_cdeg(HEAD_READINGS - 1), 14700);
}

static void ping_positions_both_directions(void)
{
    /* Reading 0: centre at unit 4 (−147°); pings at −149.25, −147.75, −146.25, −144.75 going
     * CCW, the reverse going CW. */
    const int16_t ccw[4] = {1, 3, 5, 7}, cw[4] = {7, 5, 3, 1};
    for (uint8_t j = 0; j < 4; j++) {
        CHECK_INT(motion_ping_q(0, j, 1), ccw[j]);
        CHECK_INT(motion_ping_q(0, j, -1), cw[j]);
    }
    CHECK_INT(-15000 + 75 * motion_ping_q(0, 0, 1), -14925);
    CHECK_INT(-15000 + 75 * motion_ping_q(49, 0, -1), 14925);
    CHECK_INT(-15000 + 75 * motion_ping_q(49, 3, -1), 14475);
    for (uint8_t i = 0; i < HEAD_READINGS; i++) {
        for (uint8_t j = 0; j < 4; j++) {
            int16_t a = motion_ping_q(i, j, 1), b = motion_ping_q(i, j, -1);
            CHECK(a % 2 == 1 && b % 2 == 1); /* pings on odd units */
            CHECK(a > 0 && a < HEAD_MAX_UNITS);
            CHECK_INT(a + b, 8 * (2 * i + 1)); /* mirror images about the centre */
        }
        /* Consecutive pings are one 1.5° step apart, also across readings. */
        if (i > 0) {
            CHECK_INT(motion_ping_q(i, 0, 1) - motion_ping_q((uint8_t)(i - 1), 3, 1), 2);
        }
    }
}

static void segment_ends(void)
{
    int16_t lo, hi;
    motion_segment_ends(20, 29, &lo, &hi); /* centres −27° … +27° */
    CHECK_INT(lo, 161);
    CHECK_INT(hi, 239);
    CHECK_INT(-15000 + 75 * lo, -2925);
    CHECK_INT(-15000 + 75 * hi, 2925);
    motion_segment_ends(0, 49, &lo, &hi);
    CHECK_INT(lo, 1);
    CHECK_INT(hi, 399);
    CHECK_INT(lo, motion_ping_q(20 - 20, 0, 1));
}

void motion_tests(void)
{
    RUN(halfstep_sequence);
    RUN(halfstep_sequence_direction);
    RUN(paper_motor_is_exact);
    RUN(motor_rounding_over_the_sweep);
    RUN(motor_rounding_28byj48_no_drift_over_many_sweeps);
    RUN(angles_over_the_homing_range);
    RUN(homing_limits);
    RUN(reading_centres);
    RUN(ping_positions_both_directions);
    RUN(segment_ends);
}
