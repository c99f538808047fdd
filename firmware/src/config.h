/*
 * config.h — build settings (make MOTOR=… STEPPER=… GEAR=…) and every timing or geometry constant.
 * Facts cited as "sensor-facts" come from shared/docs/sensor-facts.md, which collects the
 * datasheets; the head geometry is the paper's (§II.A) and the wire protocol's (docs/protocol.md).
 */
#ifndef SONAR_CONFIG_H
#define SONAR_CONFIG_H

/* ---- build settings -------------------------------------------------------------------------- */

/* MOTOR: which stepper turns the head. The Makefile passes exactly one of these. */
#if !defined(CFG_MOTOR_PAPER) && !defined(CFG_MOTOR_28BYJ48) && !defined(CFG_MOTOR_NEMA17)
#define CFG_MOTOR_PAPER 1
#endif

/* STEPPER: the driver stage. ULN2003 (the paper's Darlington array) or a STEP/DIR driver. */
#if !defined(CFG_STEPPER_ULN2003) && !defined(CFG_STEPPER_STEPDIR)
#if defined(CFG_MOTOR_NEMA17)
#define CFG_STEPPER_STEPDIR 1
#else
#define CFG_STEPPER_ULN2003 1
#endif
#endif

#if defined(CFG_MOTOR_PAPER)
/* Paper §II.A.2: a 7.5° motor (48 full steps per revolution), half-stepped (96 per revolution),
 * through the 1:5 gear: 480 half steps per output revolution, one per 0.75°. */
#ifndef CFG_GEAR
#define CFG_GEAR 5
#endif
#define MOTOR_BASE_NUM 96UL /* 48 full steps × 2 half steps */
#define MOTOR_DEN 1UL
#define MOTOR_NAME "paper 7.5 deg + 1:5 gear"
/* 480 half steps per turn: ±150° are whole half steps, the limits need no creeping (motion.h). */
#define LIMIT_SEEK_MICROSTEPS 0
#ifndef STEP_INTERVAL_US
#define STEP_INTERVAL_US 5000UL /* 10 ms per 1.5° step, the Rust model's Timing::step_time_ms */
#endif

#elif defined(CFG_MOTOR_28BYJ48)
/* sensor-facts: 28BYJ-48, 32 full steps per motor revolution × gearbox 63.684 (exactly
 * 25792/405); half-stepped: 64 × 25792/405 = 1650688/405 ≈ 4075.8 half steps per output
 * revolution, 16.98 per 1.5° (the fraction is kept, so the sweep does not drift). */
#ifndef CFG_GEAR
#define CFG_GEAR 1
#endif
#define MOTOR_BASE_NUM 1650688UL /* 64 × 25792 */
#define MOTOR_DEN 405UL
#define MOTOR_NAME "28BYJ-48 half-stepped"
/* 300° = 3396.48 half steps: the limit rounds half a step short, and homing's zero lies up to one
 * half step beyond −150°; two more half steps (0.18°) reach a switch at exactly ±150°. */
#define LIMIT_SEEK_MICROSTEPS 2
#ifndef STEP_INTERVAL_US
/* 500 half steps/s = 7.4 rpm at the output; sensor-facts: ~10–15 rpm at most. */
#define STEP_INTERVAL_US 2000UL
#endif

#elif defined(CFG_MOTOR_NEMA17)
/* sensor-facts: a 1.8° NEMA 17 (200 steps) at 1/16 microstep on an A4988 (Allegro datasheet):
 * 3200 microsteps per revolution, 13.33 per 1.5°. */
#ifndef CFG_GEAR
#define CFG_GEAR 1
#endif
#define MOTOR_BASE_NUM 3200UL /* 200 × 16 */
#define MOTOR_DEN 1UL
#define MOTOR_NAME "NEMA 17 at 1/16 microstep"
/* 300° = 2666.67 microsteps: as for the 28BYJ-48, up to two more (0.23°) reach the switch. */
#define LIMIT_SEEK_MICROSTEPS 2
#ifndef STEP_INTERVAL_US
#define STEP_INTERVAL_US 500UL
#endif
#endif

/* Microsteps per OUTPUT revolution = MOTOR_NUM / MOTOR_DEN exactly. */
#define MOTOR_NUM (MOTOR_BASE_NUM * (unsigned long)CFG_GEAR)

/* ---- the servo head (make HEAD=servo, servo.h) ----------------------------------------------- */

#if defined(CFG_HEAD_SERVO)
/* The sweep limits, in the servo's own degrees (0…180; 90 = the sensor's forward axis). */
#ifndef SERVO_MIN_DEG
#define SERVO_MIN_DEG 0
#endif
#ifndef SERVO_MAX_DEG
#define SERVO_MAX_DEG 180
#endif
/* TowerPro SG90 datasheet: PWM period 20 ms (50 Hz); "~1 ms" pulse at one end (-90°), 1.5 ms in
 * the middle, "~2 ms" at the other end (+90°). The MG90S datasheet gives the same. Servos differ:
 * `make HEAD=servo SERVO_US=500-2500` for one that needs wider pulses to reach 180°. */
#ifndef SERVO_PULSE_MIN_US
#define SERVO_PULSE_MIN_US 1000
#endif
#ifndef SERVO_PULSE_MAX_US
#define SERVO_PULSE_MAX_US 2000
#endif
#define SERVO_PERIOD_US 20000UL
/* SG90 datasheet: operating speed 0.1 s/60° at 4.8 V (MG90S: 0.1 s/60° at 4.8 V, 0.08 s at 6 V).
 * A slower supply or a heavier sensor mount: raise it (make SERVO_MS_PER_60=…). */
#ifndef SERVO_MS_PER_60DEG
#define SERVO_MS_PER_60DEG 100UL
#endif
/* After the move the horn and the sensor on it ring; no datasheet gives how long: 20 ms, assumed. */
#ifndef SERVO_RING_MS
#define SERVO_RING_MS 20UL
#endif
/* HC-SR04 datasheet: "we suggest to use over 60ms measurement cycle". */
#ifndef PING_INTERVAL_MS
#define PING_INTERVAL_MS 60UL
#endif
#define FIRMWARE_NAME "sonar-head 0.2.0 servo"
#else
#define FIRMWARE_NAME "sonar-head 0.2.0"
#endif

/* ---- head geometry (docs/protocol.md, paper §II.A.2) ----------------------------------------- */

#define HEAD_STEP_CDEG 150    /* one 1.5° step: 7.5° motor step through the 1:5 gear (paper) */
#define HEAD_PINGS 4          /* pings per 6° reading (paper: "four such readings are averaged") */
#define HEAD_MIN_CDEG (-15000) /* MIN limit switch, −150° (paper: 300° sweep) */
#define HEAD_MAX_CDEG 15000    /* MAX limit switch, +150° */
/* Head positions are counted in units of half a step (0.75°) from the MIN switch: pings sit on
 * odd units, the limits on even ones (0 and 400), like the Rust model's half steps. */
#define HEAD_UNIT_CDEG (HEAD_STEP_CDEG / 2)
#define HEAD_UNITS_PER_REV (36000L / HEAD_UNIT_CDEG) /* 480 */
#define HEAD_MAX_UNITS ((HEAD_MAX_CDEG - HEAD_MIN_CDEG) / HEAD_UNIT_CDEG) /* 400 */
#define HEAD_READINGS (HEAD_MAX_UNITS / (2 * HEAD_PINGS))                 /* 50 */
/* A switch closing more than this many units (1.5°) before its limit, or still open this far past
 * it, is a hardware fault: the head stops (motion.h). */
#define HEAD_SWITCH_TOLERANCE_UNITS 2
/* Homing gives up after one sweep without the MIN switch: 300° (from +150°, the farthest the MIN
 * switch can be) plus a 15° margin (a head powered on past the MAX switch, up to a mechanical stop
 * 10° beyond it, and the switch tolerance). Never more travel than that without a switch. */
#define HOMING_SWEEP_DEG 300UL
#define HOMING_MARGIN_DEG 15UL
#define HOMING_MAX_DEG (HOMING_SWEEP_DEG + HOMING_MARGIN_DEG)
/* Homing from on or beyond the MIN switch: leave it by at most 30° (a switch still closed after
 * that is stuck), then go on 3° past the point where it opened, beyond its 1–10 ms bounce, before
 * seeking it again (units of 0.75°). */
#define HOME_LEAVE_MAX_UNITS 40
#define HOME_CLEAR_UNITS 4

/* ---- timing ---------------------------------------------------------------------------------- */

/* Wait after the last motor step before a ping, so the head has stopped swinging. */
#ifndef SETTLE_MS
#define SETTLE_MS 10UL
#endif
/* sensor-facts: ≥ 50 ms between pings (HC-SR04 datasheet says > 60 ms; NewPing uses ≥ 29 ms),
 * so the previous burst has died out. */
#ifndef PING_INTERVAL_MS
#define PING_INTERVAL_MS 50UL
#endif
/* `make PING_MS=…`: the echo of the previous ping (≤ 38 ms of echo line, the HC-SR04's time-out)
 * must be over, and a reading's four pings (≤ 1 s) stay well inside the driver's 3 s
 * --silence-timeout. */
_Static_assert(PING_INTERVAL_MS >= 40UL && PING_INTERVAL_MS <= 250UL,
               "PING_MS must lie between 40 and 250 ms");
/* sensor-facts / paper §II.A.1: trigger pulse ≥ 10 µs; 12 µs leaves a margin. */
#define SONAR_TRIG_PULSE_US 12
/* sensor-facts: with no echo the SRF05 drops its echo line after ≈ 30 ms (HC-SR04 ≈ 38 ms); a
 * pulse this long is no echo. 28 ms ≈ 4.8 m at 343 m/s, beyond the 4 m range (sensor-facts). */
#define SONAR_NO_ECHO_US 28000UL
/* No falling edge this long after the rising one is also no echo (Timer1 wraps every 32.8 ms). */
#define SONAR_FALL_TIMEOUT_MS 32UL
/* The echo line rises a few hundred µs after the trigger (8 cycles at 40 kHz are sent first);
 * none within 5 ms means the module is silent or missing. */
#define SONAR_RISE_TIMEOUT_MS 5UL
/* sensor-facts: mechanical limit switches bounce for 1–10 ms. */
#define SWITCH_DEBOUNCE_MS 10u
/* De-energise the motor after this long idle (0 = never); the same phase is restored first. */
#ifndef DEENERGISE_IDLE_MS
#define DEENERGISE_IDLE_MS 1000UL
#endif
/* A4988: STEP high ≥ 1 µs, DRV8825: ≥ 1.9 µs; DIR set-up ≥ 200 ns / 650 ns (Allegro, TI). */
#define STEPDIR_PULSE_US 3
#define STEPDIR_SETUP_US 2

/* ---- EEPROM layout --------------------------------------------------------------------------- */

#define EE_HEAD_ID_ADDR 0  /* bytes 0..7: head id (8 random bytes made at the first boot) */
#define EE_HEAD_ID_CRC_ADDR 8 /* bytes 8..9: CRC-16/CCITT-FALSE of bytes 0..7, big-endian */
#define HEAD_ID_BYTES 8
#define HEAD_ID_ENTROPY_SAMPLES 64 /* WDT periods (16 ms each): ≈ 1 s once, at the first boot */

#endif
