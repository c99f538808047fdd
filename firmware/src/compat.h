/*
 * compat.h — lets the pure modules (protocol, motion, head id) build both with avr-gcc, where
 * constant strings live in flash, and with the host gcc for the unit tests.
 */
#ifndef SONAR_COMPAT_H
#define SONAR_COMPAT_H

#if defined(__AVR__)
#include <avr/pgmspace.h>
/* A string literal kept in flash (saves the 2 KiB of SRAM). */
#define FSTR(s) PSTR(s)
static inline char flash_char(const char *p)
{
    return (char)pgm_read_byte(p);
}
#else
#ifndef PROGMEM
#define PROGMEM
#endif
#define FSTR(s) (s)
static inline char flash_char(const char *p)
{
    return *p;
}
#endif

#endif
