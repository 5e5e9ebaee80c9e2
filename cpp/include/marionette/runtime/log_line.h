#pragma once

#include <iostream>
#include <sstream>
#include <string>

namespace marionette::runtime {

/// Writes one line to stderr in one write, so that the controller's threads (loop, LCM, publisher,
/// camera), which all report at start-up, never interleave their lines: `a << b << "\n"` on the
/// unbuffered std::cerr is one write per part. Callers and log readers (tests grep the log) rely on
/// each message arriving whole.
template <typename... Parts>
void LogLine(const Parts&... parts) {
  std::ostringstream line;
  (line << ... << parts);
  line << '\n';
  std::cerr << line.str() << std::flush;
}

}  // namespace marionette::runtime
