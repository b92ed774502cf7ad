// Checks for programmer errors (a wrong cv::Mat type, a size mismatch, a null output). A
// failed check prints the condition, file and line and aborts: it is a bug, not bad input.
// Bad input from outside throws InputError (errors.h) instead.
#pragma once

#include <cstdio>
#include <cstdlib>

#define ROMUNECT_CHECK(condition)                                                        \
  do {                                                                                   \
    if (!(condition)) {                                                                  \
      std::fprintf(stderr, "%s:%d: check failed: %s\n", __FILE__, __LINE__, #condition); \
      std::abort();                                                                      \
    }                                                                                    \
  } while (false)

#define ROMUNECT_CHECK_MSG(condition, message)                                                         \
  do {                                                                                                 \
    if (!(condition)) {                                                                                \
      std::fprintf(stderr, "%s:%d: check failed: %s (%s)\n", __FILE__, __LINE__, #condition, message); \
      std::abort();                                                                                    \
    }                                                                                                  \
  } while (false)

#ifdef NDEBUG
#define ROMUNECT_DCHECK(condition) \
  do {                             \
  } while (false)
#else
#define ROMUNECT_DCHECK(condition) ROMUNECT_CHECK(condition)
#endif
