/*
 * board.c: the thin C shim between sonar-firmware-sim and simavr (libsimavr, Debian 1.6).
 *
 * One ATmega328P with its firmware, and the few things the Rust side needs to play the hardware
 * around it; everything else of simavr stays behind this file (see src/avr.rs for the Rust side):
 *
 *   board_new / board_free           make a chip from an ELF at a clock frequency, free it
 *   board_run_until                  run until a cycle, a watched port changes, or the core stops;
 *                                    returns the core's state (running, sleeping, done, crashed)
 *   board_cycle / board_pc / board_resets
 *   board_watch_port / board_next_event
 *                                    queue every change of a port's pin levels (IOPORT_IRQ_PIN_ALL)
 *                                    with its cycle, instead of calling back into Rust mid-instruction
 *   board_watch_oc1b                 queue every pulse Timer1's fast PWM makes on OC1B (PB2, the
 *                                    servo's signal) with its width (see board_oc1b_pulse)
 *   board_drive_pin                  drive an input pin from outside (a switch, the ECHO line)
 *   board_uart_take                  bytes the firmware sent on UART0
 *   board_uart_ready / board_uart_send
 *                                    bytes into UART0, only while its receiver signals XON
 *   board_reset                      the reset button (pins driven from outside keep their levels)
 *   board_eeprom_write / board_eeprom_read
 *   board_lost                       events and output bytes lost to full queues
 *   board_set_logger                 simavr's log messages to a callback instead of stdout
 *
 * Not thread-safe: one thread owns a board. The logger is global to the process (simavr's is).
 */
#include <stdarg.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "sim_avr.h"
#include "sim_elf.h"
#include "avr_ioport.h"
#include "avr_uart.h"
#include "avr_eeprom.h"
#include "avr_timer.h"
#include "sim_interrupts.h"

#define BOARD_PORTS 4     /* A..D; the ATmega328P has B, C and D */
#define BOARD_EVENTS 256  /* pin-change events between two board_next_event drains */
#define BOARD_UART_OUT 8192

enum {
	BOARD_RUNNING = 0,
	BOARD_SLEEPING = 1,
	BOARD_DONE = 2,    /* sleeping with interrupts off: the firmware stopped itself */
	BOARD_CRASHED = 3, /* invalid opcode, bad jump, stack overflow... */
	BOARD_OTHER = 4,   /* limbo, stopped, gdb step states: not expected here */
};

#define BOARD_WHOLE_PORT 0xFF

typedef struct board_event_t {
	uint64_t cycle;
	char port;
	uint8_t value;  /* the port's levels */
	uint8_t pin;    /* BOARD_WHOLE_PORT, or the pin of a pulse (board_watch_oc1b) */
	uint32_t width; /* a pulse's width, cycles */
} board_event_t;

typedef struct board_t board_t;

typedef struct board_watch_t {
	board_t *board;
	char port;
	int active;
} board_watch_t;



struct board_t {
	/* First member: simavr calls our reset through this io module (see board_io_reset). */
	avr_io_t io;
	avr_t *avr;
	board_watch_t watch[BOARD_PORTS];
	/* Levels we drive on input pins, per port: kept as the port's "external" state so that the
	 * firmware's own writes to PORTx (pull-ups) do not override them, and restored after a reset. */
	uint8_t ext_mask[BOARD_PORTS];
	uint8_t ext_value[BOARD_PORTS];
	board_event_t events[BOARD_EVENTS];
	size_t ev_head, ev_len;
	uint64_t ev_lost;
	uint8_t uart_out[BOARD_UART_OUT];
	size_t out_len;
	uint64_t out_lost;
	int xon;
	uint32_t resets;
};

static void (*board_logger)(int level, const char *msg);

static void board_log_forward(avr_t *avr, const int level, const char *format, va_list ap)
{
	(void)avr;
	/* Errors and warnings only: traces are per instruction or per register access. */
	if (!board_logger || level > LOG_WARNING)
		return;
	char msg[512];
	vsnprintf(msg, sizeof msg, format, ap);
	size_t n = strlen(msg);
	while (n && (msg[n - 1] == '\n' || msg[n - 1] == '\r'))
		msg[--n] = 0;
	board_logger(level, msg);
}

void board_set_logger(void (*cb)(int level, const char *msg))
{
	board_logger = cb;
	avr_global_logger_set(cb ? board_log_forward : NULL);
}

static int port_index(char port)
{
	return (port >= 'A' && port < 'A' + BOARD_PORTS) ? port - 'A' : -1;
}

static void board_push_event(board_t *b, char port, uint8_t pin, uint8_t value, uint32_t width)
{
	if (b->ev_len == BOARD_EVENTS) {
		b->ev_lost++;
		return;
	}
	board_event_t *e = &b->events[(b->ev_head + b->ev_len) % BOARD_EVENTS];
	e->cycle = b->avr->cycle;
	e->port = port;
	e->value = value;
	e->pin = pin;
	e->width = width;
	b->ev_len++;
}

static void on_port_change(struct avr_irq_t *irq, uint32_t value, void *param)
{
	(void)irq;
	board_watch_t *w = param;
	board_push_event(w->board, w->port, BOARD_WHOLE_PORT, (uint8_t)value, 0);
}

/*
 * Timer1's compare unit B has just cleared OC1B: a pulse of the servo's signal ends. Its width is
 * taken as the datasheet defines it for fast PWM with COM1B = 2 (ATmega328P §16.9.3: OC1B set at
 * BOTTOM, cleared at the compare match: OCR1B + 1 timer ticks), not from simavr's rising edge:
 * simavr 1.6 sets that edge late at times under this firmware (seen: pulses of 527-939 us where
 * 1004 us was asked, while its compare matches stay in time). Only while PB2 is an output (simavr
 * raises the compare output whatever the pin's direction) and Timer1 is in fast PWM (modes 14, 15).
 */
static void board_oc1b_pulse(struct avr_irq_t *irq, uint32_t value, void *param)
{
	(void)irq;
	board_t *b = param;
	avr_t *avr = b->avr;
	if (value & 1)
		return; /* the start of a pulse: its end reports it */
	avr_ioport_state_t st;
	if (avr_ioctl(avr, AVR_IOCTL_IOPORT_GETSTATE('B'), &st) != 0 || !(st.ddr & (1u << 2)))
		return;
	uint8_t tccr1a = avr->data[0x80], tccr1b = avr->data[0x81];
	uint8_t wgm = (uint8_t)((tccr1a & 3) | ((tccr1b >> 1) & 0xC));
	uint8_t com1b = (uint8_t)((tccr1a >> 4) & 3);
	static const uint16_t prescale[8] = {0, 1, 8, 64, 256, 1024, 0, 0};
	uint16_t div = prescale[tccr1b & 7];
	if ((wgm != 14 && wgm != 15) || com1b != 2 || div == 0)
		return;
	uint32_t ocr1b = (uint32_t)avr->data[0x8A] | ((uint32_t)avr->data[0x8B] << 8);
	board_push_event(b, 'B', 2, 0, (ocr1b + 1) * div);
}

static void on_uart_output(struct avr_irq_t *irq, uint32_t value, void *param)
{
	(void)irq;
	board_t *b = param;
	if (b->out_len == BOARD_UART_OUT) {
		b->out_lost++;
		return;
	}
	b->uart_out[b->out_len++] = (uint8_t)value;
}

/* XON is raised (repeatedly) while the receive fifo has room and the receiver is on; XOFF with 1
 * when it is full or the receiver is switched off. */
static void on_uart_xon(struct avr_irq_t *irq, uint32_t value, void *param)
{
	(void)irq;
	board_t *b = param;
	if (value)
		b->xon = 1;
}

static void on_uart_xoff(struct avr_irq_t *irq, uint32_t value, void *param)
{
	(void)irq;
	board_t *b = param;
	if (value)
		b->xon = 0;
}

/* The level the firmware reads on every pin of a port, as the port's PIN_ALL irq reports it. */
static int port_levels(avr_t *avr, char port, uint8_t *levels)
{
	avr_ioport_state_t st;
	if (avr_ioctl(avr, AVR_IOCTL_IOPORT_GETSTATE(port), &st) != 0)
		return -1;
	*levels = (uint8_t)((st.pin & ~st.ddr) | (st.port & st.ddr));
	return 0;
}

/*
 * Called by avr_reset (any reset: ours, the watchdog's) after the core cleared every I/O
 * register. On the real chip the PIN registers keep reading the pins, so the levels we drive are
 * put back; and the watched ports, whose outputs just went to high impedance, report their new
 * levels (simavr raises nothing for that itself).
 */
static void board_io_reset(avr_io_t *io)
{
	board_t *b = (board_t *)io;
	avr_t *avr = b->avr;
	b->resets++;
	b->xon = 0; /* the receiver is off until the firmware enables it again */
	for (int i = 0; i < BOARD_PORTS; i++) {
		char port = (char)('A' + i);
		for (int pin = 0; pin < 8; pin++) {
			if (!(b->ext_mask[i] & (1 << pin)))
				continue;
			avr_irq_t *irq = avr_io_getirq(avr, AVR_IOCTL_IOPORT_GETIRQ(port), pin);
			if (!irq)
				continue;
			irq->flags |= IRQ_FLAG_INIT; /* pass the same-value filter once */
			avr_raise_irq(irq, (b->ext_value[i] >> pin) & 1);
		}
		uint8_t levels;
		if (b->watch[i].active && port_levels(avr, port, &levels) == 0) {
			avr_irq_t *all = avr_io_getirq(avr, AVR_IOCTL_IOPORT_GETIRQ(port), IOPORT_IRQ_PIN_ALL);
			if (all)
				avr_raise_irq(all, levels);
		}
	}
}

/* The core would usleep() to keep to real time while the firmware sleeps: we pace ourselves. */
static void board_no_sleep(avr_t *avr, avr_cycle_count_t how_long)
{
	(void)avr;
	(void)how_long;
}

/* A no-op timer at the end of a run, so that a sleeping core wakes there and not later. */
static avr_cycle_count_t board_wake(avr_t *avr, avr_cycle_count_t when, void *param)
{
	(void)avr;
	(void)when;
	(void)param;
	return 0;
}

static void set_err(char *err, size_t err_len, const char *fmt, ...)
{
	if (!err || !err_len)
		return;
	va_list ap;
	va_start(ap, fmt);
	vsnprintf(err, err_len, fmt, ap);
	va_end(ap);
}

static void free_firmware(elf_firmware_t *f)
{
	free(f->flash);
	free(f->eeprom);
	free(f->fuse);
	free(f->lockbits);
#if ELF_SYMBOLS
	for (uint32_t i = 0; i < f->symbolcount; i++)
		free(f->symbol[i]);
	free(f->symbol);
#endif
	free(f);
}

/*
 * simavr 1.6 (Debian's) clears every raised flag of a timer's interrupt flag register on any write
 * to it: its avr_timer_write_pending() ignores the value written. The firmware writes
 * TIFR1 = _BV(ICF1) (datasheet §16.11.9: a flag is cleared by writing a logical one to it, the
 * others are left alone) around each echo edge with interrupts off; an overflow raised just then
 * was lost with it, and the echo's timestamps came out 65536 ticks (32.8 ms) apart: an echo
 * reported as none, about 5 times in 12 000 pings. Fixed upstream in 2021 (simavr pull request
 * 415); until the distribution ships that, the board installs a write-one-to-clear handler for
 * Timer1's flags.
 */
static void board_timer_flags_write(avr_t *avr, avr_io_addr_t addr, uint8_t v, void *param)
{
	avr_timer_t *p = param;
	if (addr == p->overflow.raised.reg && avr_regbit_from_value(avr, p->overflow.raised, v))
		avr_clear_interrupt(avr, &p->overflow);
	if (addr == p->icr.raised.reg && avr_regbit_from_value(avr, p->icr.raised, v))
		avr_clear_interrupt(avr, &p->icr);
	for (int i = 0; i < AVR_TIMER_COMP_COUNT; i++) {
		avr_int_vector_t *comp = &p->comp[i].interrupt;
		if (addr == comp->raised.reg && avr_regbit_from_value(avr, comp->raised, v))
			avr_clear_interrupt(avr, comp);
	}
}

/* Installs board_timer_flags_write for Timer1's TIFR1; 0 when done, -1 when the register is not
 * Timer1's alone (another simavr than the one this was written for: left as it is). */
static int board_fix_timer1_flags(avr_t *avr)
{
	for (avr_io_t *io = avr->io_port; io; io = io->next) {
		if (!io->kind || strcmp(io->kind, "timer") != 0)
			continue;
		avr_timer_t *t = (avr_timer_t *)io;
		if (t->name != '1')
			continue;
		avr_io_addr_t reg = t->overflow.raised.reg;
		if (!reg || reg != t->icr.raised.reg)
			return -1;
		int a = AVR_DATA_TO_IO(reg);
		if (a < 0 || a >= MAX_IOs || avr->io[a].w.param != t)
			return -1;
		avr->io[a].w.c = board_timer_flags_write;
		return 0;
	}
	return -1;
}

board_t *board_new(const char *elf_path, uint32_t frequency, char *err, size_t err_len)
{
	elf_firmware_t *f = calloc(1, sizeof *f);
	if (!f) {
		set_err(err, err_len, "out of memory");
		return NULL;
	}
	if (elf_read_firmware(elf_path, f) != 0) {
		set_err(err, err_len, "cannot read %s as an AVR ELF file", elf_path);
		free_firmware(f);
		return NULL;
	}
	if (f->mmcu[0] && strcmp(f->mmcu, "atmega328p") != 0) {
		set_err(err, err_len, "%s is built for %s, not the atmega328p", elf_path, f->mmcu);
		free_firmware(f);
		return NULL;
	}
	avr_t *avr = avr_make_mcu_by_name("atmega328p");
	if (!avr) {
		set_err(err, err_len, "this simavr has no atmega328p core");
		free_firmware(f);
		return NULL;
	}
	avr_init(avr);
	if ((uint64_t)f->flashbase + f->flashsize > (uint64_t)avr->flashend + 1) {
		/* avr_loadcode would abort() */
		set_err(err, err_len, "%s has %u bytes of code, the atmega328p %u", elf_path,
			f->flashbase + f->flashsize, avr->flashend + 1);
		avr_terminate(avr);
		free(avr);
		free_firmware(f);
		return NULL;
	}
	avr_load_firmware(avr, f);
	free_firmware(f);
	if (board_fix_timer1_flags(avr) != 0)
		AVR_LOG(avr, LOG_WARNING,
			"board: Timer1's TIFR1 write handler not replaced: pending overflows may be lost\n");
	avr->frequency = frequency; /* the board's crystal, whatever the ELF says */
	avr->sleep = board_no_sleep;
	avr->log = LOG_WARNING;

	board_t *b = calloc(1, sizeof *b);
	if (!b) {
		set_err(err, err_len, "out of memory");
		avr_terminate(avr);
		free(avr);
		return NULL;
	}
	b->avr = avr;
	b->io.kind = "sonar-board";
	b->io.reset = board_io_reset;
	avr_register_io(avr, &b->io);

	/* No console echo of UART lines and no usleep() while the firmware polls UCSR0A. */
	uint32_t uart_flags = 0;
	avr_ioctl(avr, AVR_IOCTL_UART_SET_FLAGS('0'), &uart_flags);
	avr_irq_register_notify(avr_io_getirq(avr, AVR_IOCTL_UART_GETIRQ('0'), UART_IRQ_OUTPUT),
				on_uart_output, b);
	avr_irq_register_notify(avr_io_getirq(avr, AVR_IOCTL_UART_GETIRQ('0'), UART_IRQ_OUT_XON),
				on_uart_xon, b);
	avr_irq_register_notify(avr_io_getirq(avr, AVR_IOCTL_UART_GETIRQ('0'), UART_IRQ_OUT_XOFF),
				on_uart_xoff, b);
	return b;
}

void board_free(board_t *b)
{
	if (!b)
		return;
	avr_terminate(b->avr); /* also unlinks our io module from the core */
	free(b->avr);
	free(b);
}

uint64_t board_cycle(const board_t *b)
{
	return b->avr->cycle;
}

uint32_t board_pc(const board_t *b)
{
	return b->avr->pc;
}

uint32_t board_resets(const board_t *b)
{
	return b->resets;
}

static int board_state(const board_t *b)
{
	switch (b->avr->state) {
	case cpu_Running:
		return BOARD_RUNNING;
	case cpu_Sleeping:
		return BOARD_SLEEPING;
	case cpu_Done:
		return BOARD_DONE;
	case cpu_Crashed:
		return BOARD_CRASHED;
	default:
		return BOARD_OTHER;
	}
}

int board_run_until(board_t *b, uint64_t until)
{
	avr_t *avr = b->avr;
	if (avr->cycle < until)
		avr_cycle_timer_register(avr, until - avr->cycle, board_wake, b);
	while (avr->cycle < until && b->ev_len == 0) {
		int state = avr_run(avr);
		if (state != cpu_Running && state != cpu_Sleeping)
			break;
	}
	avr_cycle_timer_cancel(avr, board_wake, b);
	return board_state(b);
}

int board_watch_port(board_t *b, char port)
{
	int i = port_index(port);
	if (i < 0)
		return -1;
	avr_irq_t *all = avr_io_getirq(b->avr, AVR_IOCTL_IOPORT_GETIRQ(port), IOPORT_IRQ_PIN_ALL);
	if (!all)
		return -1;
	b->watch[i].board = b;
	b->watch[i].port = port;
	b->watch[i].active = 1;
	avr_irq_register_notify(all, on_port_change, &b->watch[i]);
	return 0;
}

int board_watch_oc1b(board_t *b)
{
	avr_irq_t *irq = avr_io_getirq(b->avr, AVR_IOCTL_TIMER_GETIRQ('1'), TIMER_IRQ_OUT_COMP + 1);
	if (!irq)
		return -1;
	avr_irq_register_notify(irq, board_oc1b_pulse, b);
	return 0;
}

int board_next_event(board_t *b, board_event_t *out)
{
	if (!b->ev_len)
		return 0;
	*out = b->events[b->ev_head];
	b->ev_head = (b->ev_head + 1) % BOARD_EVENTS;
	b->ev_len--;
	return 1;
}

int board_drive_pin(board_t *b, char port, uint8_t pin, int level)
{
	int i = port_index(port);
	if (i < 0 || pin > 7)
		return -1;
	avr_irq_t *irq = avr_io_getirq(b->avr, AVR_IOCTL_IOPORT_GETIRQ(port), pin);
	if (!irq)
		return -1;
	b->ext_mask[i] |= (uint8_t)(1 << pin);
	if (level)
		b->ext_value[i] |= (uint8_t)(1 << pin);
	else
		b->ext_value[i] &= (uint8_t)~(1 << pin);
	avr_ioport_external_t ext = {
		.name = (unsigned long)port,
		.mask = b->ext_mask[i],
		.value = b->ext_value[i],
	};
	if (avr_ioctl(b->avr, AVR_IOCTL_IOPORT_SET_EXTERNAL(port), &ext) != 0)
		return -1;
	avr_raise_irq(irq, level ? 1 : 0);
	return 0;
}

size_t board_uart_take(board_t *b, uint8_t *buf, size_t cap)
{
	size_t n = b->out_len < cap ? b->out_len : cap;
	memcpy(buf, b->uart_out, n);
	memmove(b->uart_out, b->uart_out + n, b->out_len - n);
	b->out_len -= n;
	return n;
}

int board_uart_ready(const board_t *b)
{
	return b->xon;
}

void board_uart_send(board_t *b, uint8_t byte)
{
	avr_raise_irq(avr_io_getirq(b->avr, AVR_IOCTL_UART_GETIRQ('0'), UART_IRQ_INPUT), byte);
}

void board_reset(board_t *b)
{
	avr_reset(b->avr);
}

static int eeprom_range_ok(const board_t *b, uint16_t offset, uint32_t len)
{
	return len > 0 && (uint64_t)offset + len <= (uint64_t)b->avr->e2end + 1;
}

int board_eeprom_write(board_t *b, uint16_t offset, const uint8_t *data, uint32_t len)
{
	if (!eeprom_range_ok(b, offset, len))
		return -1;
	avr_eeprom_desc_t d = { .ee = (uint8_t *)data, .offset = offset, .size = len };
	/* simavr answers -1 ("no module took it") on success too; -2 is a refusal. */
	return avr_ioctl(b->avr, AVR_IOCTL_EEPROM_SET, &d) == -2 ? -1 : 0;
}

int board_eeprom_read(board_t *b, uint16_t offset, uint8_t *data, uint32_t len)
{
	if (!eeprom_range_ok(b, offset, len))
		return -1;
	avr_eeprom_desc_t d = { .ee = data, .offset = offset, .size = len };
	return avr_ioctl(b->avr, AVR_IOCTL_EEPROM_GET, &d) == -2 ? -1 : 0;
}

void board_lost(const board_t *b, uint64_t *events, uint64_t *uart_bytes)
{
	*events = b->ev_lost;
	*uart_bytes = b->out_lost;
}
