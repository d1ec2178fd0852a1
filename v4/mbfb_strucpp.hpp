/* mbfb_strucpp.hpp - what the {external} form of the blocks' pragmas needs under STruC++.
 *
 * The matiec pragmas ({{ }} in st_src) reach a block's variables as C values: GetFbVar(X),
 * SetFbVar(X, v) and &data__->X.value (a pointer to X laid out as C: STRING as {len, body},
 * arrays as packed elements, structures as C structures). STruC++ keeps every variable in an
 * IECVar<T> (value + forcing state), so an array of WORD is not a uint16_t[] and a pointer
 * cast would be wrong. v4/translate.py therefore gives each pragma a C mirror of every
 * variable it names (ctype<decltype(X)>::type), copied in before the pragma's statements and
 * back after them (to_c / from_c below): the shims see the same C layout as under matiec.
 *
 * The generated code includes this header through the .stlib manifest's "headers" entry
 * (STruC++ src/index.ts: archive.manifest.headers -> #include in the generated header). */
#pragma once
#include <cstddef>
#include <cstdint>
#include <cstring>
#include <type_traits>
#include "iec_var.hpp"
#include "iec_string.hpp"
#include "iec_array.hpp"
#include "iec_std_lib.hpp"
#include "mbfb.h"

/* A TIME in a pragma is STruC++'s integer (mbfb.h's MBFB_TIME_EQ and MBFB_TIME_SUB work on
   matiec's {tv_sec, tv_nsec}). */
#undef MBFB_TIME_EQ
#define MBFB_TIME_EQ(a, b) ((a) == (b))
#undef MBFB_TIME_SUB
#define MBFB_TIME_SUB(res, a, b) ((res) = (a) - (b))

namespace mbfb_v4 {

/* matiec's STRING as a pragma sees it: a length and the characters (no terminator). */
struct mstring {
    int len;
    uint8_t body[256];
};

/* matiec's C names of the elementary types, for casts written in a pragma ((DINT)x). */
namespace matiec_types {
typedef uint8_t BOOL;
typedef int8_t SINT;
typedef int16_t INT;
typedef int32_t DINT;
typedef int64_t LINT;
typedef uint8_t USINT;
typedef uint16_t UINT;
typedef uint32_t UDINT;
typedef uint64_t ULINT;
typedef uint8_t BYTE;
typedef uint16_t WORD;
typedef uint32_t DWORD;
typedef uint64_t LWORD;
typedef float REAL;
typedef double LREAL;
}  // namespace matiec_types

template <class T, class = void> struct ctype;               /* the C mirror of an IEC variable */
template <class T> struct ctype<strucpp::IECVar<T>, typename std::enable_if<std::is_arithmetic<T>::value>::type> {
    using type = T;
};
template <size_t N> struct ctype<strucpp::IECStringVar<N>> { using type = mstring; };
template <size_t N> struct ctype<strucpp::IECVar<strucpp::IECString<N>>> { using type = mstring; };
template <class E, class B> struct ctype<strucpp::IEC_ARRAY_1D<E, B>> {
    using type = typename ctype<E>::type[B::size];
};
template <class T> using ctype_t = typename ctype<typename std::remove_cv<T>::type>::type;

template <class T>
inline void to_c(const strucpp::IECVar<T> &v, T &c) { c = v.get(); }
/* Set only when the bits differ: == would keep +0.0 for a pragma's -0.0 and set a NaN every time. */
template <class T>
inline void from_c(const T &c, strucpp::IECVar<T> &v) {
    T now = v.get();
    if (std::memcmp(&c, &now, sizeof c) != 0) v.set(c);
}

template <class S>
inline void str_to_c(const S &s, mstring &c) {
    size_t n = s.length();
    if (n > sizeof c.body) n = sizeof c.body;
    c.len = (int)n;
    std::memcpy(c.body, s.c_str(), n);
    std::memset(c.body + n, 0, sizeof c.body - n);  /* a structure holding it compares byte for byte */
}
template <size_t N>
inline void to_c(const strucpp::IECStringVar<N> &v, mstring &c) { str_to_c(v.get(), c); }
template <size_t N>
inline void to_c(const strucpp::IECVar<strucpp::IECString<N>> &v, mstring &c) { str_to_c(v.get(), c); }

template <size_t N>
inline strucpp::IECString<N> str_from_c(const mstring &c) {
    char tmp[sizeof c.body + 1];
    int n = c.len < 0 ? 0 : (c.len > (int)N ? (int)N : c.len);
    std::memcpy(tmp, c.body, (size_t)n);  /* NOLINT: uint8_t -> char */
    tmp[n] = '\0';
    return strucpp::IECString<N>(tmp);
}
template <size_t N>
inline void from_c(const mstring &c, strucpp::IECStringVar<N> &v) {
    auto s = str_from_c<N>(c);
    if (!(s == v.get())) v.set(s);
}
template <size_t N>
inline void from_c(const mstring &c, strucpp::IECVar<strucpp::IECString<N>> &v) {
    auto s = str_from_c<N>(c);
    if (!(s == v.get())) v.set(s);
}

template <class E, class B>
inline void to_c(const strucpp::IEC_ARRAY_1D<E, B> &a, typename ctype<E>::type (&c)[B::size]) {
    for (size_t i = 0; i < B::size; i++) to_c(a[B::lower + (int64_t)i], c[i]);
}
template <class E, class B>
inline void from_c(const typename ctype<E>::type (&c)[B::size], strucpp::IEC_ARRAY_1D<E, B> &a) {
    for (size_t i = 0; i < B::size; i++) from_c(c[i], a[B::lower + (int64_t)i]);
}

/* matiec's __CURRENT_TIME in a pragma: the scan's TIME (STruC++ iec_std_lib.hpp TIME()). */
inline strucpp::TIME_t current_time() { return strucpp::TIME().get(); }

/* matiec's __time_cmp(a, b) in a pragma (iec_std_lib.h): < 0, 0, > 0 as a is before, at or
   after b. */
inline long long time_cmp(strucpp::TIME_t a, strucpp::TIME_t b) { return a < b ? -1 : (a > b ? 1 : 0); }

}  // namespace mbfb_v4
