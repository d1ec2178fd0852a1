// plc_vars.cpp - read and write a program's variables as text (plc_vars.h); the snapshot file.
#include "iec_types_all.h"
#include "plc_vars.h"

#include <errno.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <strings.h>
#include <unistd.h>
#include <string>

static const char *const TYPE_NAMES[] = {
    "BOOL", "SINT", "INT", "DINT", "LINT", "USINT", "UINT", "UDINT", "ULINT",
    "BYTE", "WORD", "DWORD", "LWORD", "REAL", "LREAL", "TIME", "STRING"};

const char *plc_type_name(plc_type_t type) { return TYPE_NAMES[type]; }

const plc_var_t *plc_var_find(const char *name) {
    for (int i = 0; i < plc_nvars; i++) {
        const char *n = plc_vars[i].name;
        if (strcasecmp(n, name) == 0 || (n[0] == '%' && strcasecmp(n + 1, name) == 0))
            return &plc_vars[i];
    }
    return NULL;
}

static bool is_signed(plc_type_t t) {
    return t == PLC_SINT || t == PLC_INT || t == PLC_DINT || t == PLC_LINT;
}

static int bits(plc_type_t t) {
    switch (t) {
    case PLC_SINT: case PLC_USINT: case PLC_BYTE: return 8;
    case PLC_INT: case PLC_UINT: case PLC_WORD: return 16;
    case PLC_DINT: case PLC_UDINT: case PLC_DWORD: return 32;
    default: return 64;
    }
}

static long long get_signed(const plc_var_t *v) {
    switch (v->type) {
    case PLC_SINT: return *(IEC_SINT *)v->ptr;
    case PLC_INT: return *(IEC_INT *)v->ptr;
    case PLC_DINT: return *(IEC_DINT *)v->ptr;
    default: return *(IEC_LINT *)v->ptr;
    }
}

static unsigned long long get_unsigned(const plc_var_t *v) {
    switch (bits(v->type)) {
    case 8: return *(IEC_USINT *)v->ptr;
    case 16: return *(IEC_UINT *)v->ptr;
    case 32: return *(IEC_UDINT *)v->ptr;
    default: return *(IEC_ULINT *)v->ptr;
    }
}

static int json_double(char *buf, size_t size, double d, int digits) {
    if (!isfinite(d)) return snprintf(buf, size, "null");  // JSON has no NaN/inf
    return snprintf(buf, size, "%.*g", digits, d);
}

static int json_string(const IEC_STRING *s, char *buf, size_t size) {
    std::string out = "\"";
    int len = s->len < STR_MAX_LEN ? s->len : STR_MAX_LEN;
    for (int i = 0; i < len; i++) {
        unsigned char c = s->body[i];
        if (c == '"' || c == '\\') {
            out += '\\';
            out += (char)c;
        } else if (c < 0x20 || c >= 0x7f) {  // bytes, not text: keep the JSON ASCII
            char esc[8];
            snprintf(esc, sizeof esc, "\\u%04x", c);
            out += esc;
        } else {
            out += (char)c;
        }
    }
    out += '"';
    return snprintf(buf, size, "%s", out.c_str());
}

int plc_var_format(const plc_var_t *v, char *buf, size_t size) {
    switch (v->type) {
    case PLC_BOOL: return snprintf(buf, size, "%s", *(IEC_BOOL *)v->ptr ? "true" : "false");
    case PLC_REAL: return json_double(buf, size, *(IEC_REAL *)v->ptr, 9);
    case PLC_LREAL: return json_double(buf, size, *(IEC_LREAL *)v->ptr, 17);
    case PLC_TIME: {
        const IEC_TIME *t = (const IEC_TIME *)v->ptr;
        return json_double(buf, size, t->tv_sec * 1e3 + t->tv_nsec / 1e6, 15);
    }
    case PLC_STRING: return json_string((const IEC_STRING *)v->ptr, buf, size);
    default:
        if (is_signed(v->type)) return snprintf(buf, size, "%lld", get_signed(v));
        return snprintf(buf, size, "%llu", get_unsigned(v));
    }
}

static int fail(int e) {
    errno = e;
    return -1;
}

static int parse_bool(const char *text, IEC_BOOL *out) {
    if (!strcasecmp(text, "true") || !strcmp(text, "1")) *out = 1;
    else if (!strcasecmp(text, "false") || !strcmp(text, "0")) *out = 0;
    else return fail(EINVAL);
    return 0;
}

static int parse_integer(const plc_var_t *v, const char *text) {
    char *end;
    errno = 0;
    int n = bits(v->type);
    if (is_signed(v->type)) {
        long long x = strtoll(text, &end, 0);
        if (end == text || *end) return fail(EINVAL);
        long long lim = n == 64 ? 0 : 1LL << (n - 1);
        if (errno == ERANGE || (n < 64 && (x < -lim || x >= lim))) return fail(ERANGE);
        switch (n) {
        case 8: *(IEC_SINT *)v->ptr = (IEC_SINT)x; break;
        case 16: *(IEC_INT *)v->ptr = (IEC_INT)x; break;
        case 32: *(IEC_DINT *)v->ptr = (IEC_DINT)x; break;
        default: *(IEC_LINT *)v->ptr = x;
        }
        return 0;
    }
    if (strchr(text, '-')) return fail(ERANGE);  // strtoull would wrap it round
    unsigned long long x = strtoull(text, &end, 0);
    if (end == text || *end) return fail(EINVAL);
    if (errno == ERANGE || (n < 64 && x >> n)) return fail(ERANGE);
    switch (n) {
    case 8: *(IEC_USINT *)v->ptr = (IEC_USINT)x; break;
    case 16: *(IEC_UINT *)v->ptr = (IEC_UINT)x; break;
    case 32: *(IEC_UDINT *)v->ptr = (IEC_UDINT)x; break;
    default: *(IEC_ULINT *)v->ptr = x;
    }
    return 0;
}

static int parse_double(const char *text, double *out) {
    char *end;
    errno = 0;
    *out = strtod(text, &end);
    if (end == text || *end || !isfinite(*out)) return fail(EINVAL);
    return errno == ERANGE ? fail(ERANGE) : 0;
}

int plc_var_parse(const plc_var_t *v, const char *text) {
    double d;
    switch (v->type) {
    case PLC_BOOL: return parse_bool(text, (IEC_BOOL *)v->ptr);
    case PLC_REAL:
        if (parse_double(text, &d)) return -1;
        if (fabs(d) > 3.4028234663852886e38) return fail(ERANGE);
        *(IEC_REAL *)v->ptr = (IEC_REAL)d;
        return 0;
    case PLC_LREAL:
        if (parse_double(text, &d)) return -1;
        *(IEC_LREAL *)v->ptr = d;
        return 0;
    case PLC_TIME: {
        if (parse_double(text, &d)) return -1;
        long long ns = llround(d * 1e6);
        IEC_TIME *t = (IEC_TIME *)v->ptr;
        t->tv_sec = ns / 1000000000LL;  // matiec's normal form: both parts share the sign
        t->tv_nsec = ns % 1000000000LL;
        return 0;
    }
    case PLC_STRING: {
        size_t len = strlen(text);
        if (len >= 2 && text[0] == '\'' && text[len - 1] == '\'') {
            text++;
            len -= 2;
        }
        if (len > STR_MAX_LEN) return fail(ERANGE);
        IEC_STRING *s = (IEC_STRING *)v->ptr;
        memcpy(s->body, text, len);
        s->len = (__strlen_t)len;
        return 0;
    }
    default: return parse_integer(v, text);
    }
}

int plc_snapshot_write(const char *path, unsigned long scan) {
    std::string json = "{\"scan\": " + std::to_string(scan);
    std::string group;
    char value[512];
    for (int i = 0; i < plc_nvars && plc_vars[i].name[0] == '%'; i++) {
        const char *name = plc_vars[i].name + 1;     // "QW0", "QX0.1"
        std::string g(name, 2), key(name + 2);
        if (g != group) {
            json += (group.empty() ? ", \"" : "}, \"") + g + "\": {";
            group = g;
        } else {
            json += ", ";
        }
        plc_var_format(&plc_vars[i], value, sizeof value);
        json += "\"" + key + "\": " + value;
    }
    json += group.empty() ? "}\n" : "}}\n";
    std::string tmp = std::string(path) + ".tmp";
    FILE *f = fopen(tmp.c_str(), "w");
    if (!f) return -1;
    size_t n = fwrite(json.data(), 1, json.size(), f);
    if (fclose(f) != 0 || n != json.size()) {
        int e = errno;
        unlink(tmp.c_str());
        return fail(e ? e : EIO);
    }
    return rename(tmp.c_str(), path);
}
