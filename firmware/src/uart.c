/*
 * uart.c — UART0, interrupt driven both ways.
 */
#include "uart.h"

#include "pins.h"

#include <avr/interrupt.h>
#include <avr/io.h>

#define RX_SIZE 64u  /* power of two */
#define TX_SIZE 256u /* power of two; 8-bit indices wrap by themselves */

static volatile uint8_t rx_buf[RX_SIZE];
static volatile uint8_t rx_head, rx_tail;
static volatile uint8_t tx_buf[TX_SIZE];
static volatile uint8_t tx_head, tx_tail;

ISR(USART_RX_vect)
{
    uint8_t b = UDR0;
    uint8_t next = (uint8_t)((rx_head + 1u) & (RX_SIZE - 1u));
    if (next != rx_tail) { /* full: the byte is lost; the line's CRC will tell */
        rx_buf[rx_head] = b;
        rx_head = next;
    }
}

ISR(USART_UDRE_vect)
{
    if (tx_head == tx_tail) {
        UCSR0B &= (uint8_t)~_BV(UDRIE0);
        return;
    }
    UDR0 = tx_buf[tx_tail];
    tx_tail = (uint8_t)(tx_tail + 1u);
}

void uart_init(void)
{
    /* Datasheet baud tables (sensor-facts): U2X with UBRR0 = 16 → 117647 baud, +2.1 %.
     * U2X first: simavr computes its byte time when UBRR0L is written (the chip does not care). */
    UCSR0A = UART_U2X ? _BV(U2X0) : 0;
    UBRR0H = (uint8_t)(UART_UBRR >> 8);
    UBRR0L = (uint8_t)UART_UBRR;
    UCSR0C = _BV(UCSZ01) | _BV(UCSZ00); /* 8 data bits, no parity, 1 stop bit */
    UCSR0B = _BV(RXEN0) | _BV(TXEN0) | _BV(RXCIE0);
}

bool uart_read(uint8_t *byte)
{
    if (rx_head == rx_tail) {
        return false;
    }
    *byte = rx_buf[rx_tail];
    rx_tail = (uint8_t)((rx_tail + 1u) & (RX_SIZE - 1u));
    return true;
}

void uart_write(const char *s, uint8_t len)
{
    for (uint8_t i = 0; i < len; i++) {
        uint8_t next = (uint8_t)(tx_head + 1u);
        while (next == tx_tail) {
            /* Full: the UDRE interrupt makes room (87 µs per byte). Interrupts are on here. */
        }
        tx_buf[tx_head] = (uint8_t)s[i];
        tx_head = next;
        UCSR0B |= _BV(UDRIE0);
    }
}

bool uart_tx_idle(void)
{
    return tx_head == tx_tail && (UCSR0A & _BV(UDRE0));
}
