/*
 * uart.h — UART0 at 115200 8N1 (pins.h). RX: interrupt into a 64-byte ring; TX: a 256-byte ring
 * drained by the UDRE interrupt (uart_write waits for room when it is full, never longer).
 */
#ifndef SONAR_UART_H
#define SONAR_UART_H

#include <stdbool.h>
#include <stdint.h>

void uart_init(void);
/* Next received byte; false if none. */
bool uart_read(uint8_t *byte);
void uart_write(const char *s, uint8_t len);
/* True once every queued byte has left the shift register's holding buffer. */
bool uart_tx_idle(void);

#endif
