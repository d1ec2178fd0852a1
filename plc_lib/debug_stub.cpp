// Debugger tables for a program with no debug variables: the DBG section of a web-upload
// bundle made by plc_lib/mkbundle.sh. OpenPLC's runtime links these symbols (see its
// core/debug.h and modbus.cpp); the OpenPLC Editor normally generates them with one entry per
// program variable. An empty table keeps the program running; the Editor's debugger shows nothing.
#include <stdint.h>
#include <stddef.h>

char md5[] = "00000000000000000000000000000000";
uint8_t endianness;
uint16_t get_var_count(void) { return 0; }
size_t get_var_size(size_t idx) { (void)idx; return 0; }
void *get_var_addr(size_t idx) { (void)idx; return NULL; }
void force_var(size_t idx, bool forced, void *val) { (void)idx; (void)forced; (void)val; }
void trace_reset(void) {}
void set_trace(size_t idx, bool forced, void *val) { (void)idx; (void)forced; (void)val; }
void set_endianness(uint8_t value) { if (value <= 1) endianness = value; }
