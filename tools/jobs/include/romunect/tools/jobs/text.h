// Text for terminals and reports: printf-style formatting into a string of the size it needs
// (numbers keep the precision their format gives, as the reports always showed them).
#pragma once

#include <string>

namespace romunect::jobs {

std::string Format(const char* format, ...) __attribute__((format(printf, 1, 2)));

}  // namespace romunect::jobs
