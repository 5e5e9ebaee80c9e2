// Command-line values shared by marionette-controller and marionette-sim (command_line.h).
#include "marionette/controller/command_line.h"

#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <sstream>
#include <stdexcept>

namespace marionette::controller {

double ParseNonNegative(const std::string& flag, const std::string& text) {
  char* end = nullptr;
  const double x = std::strtod(text.c_str(), &end);
  if (end == text.c_str() || *end != '\0' || !std::isfinite(x) || x < 0.0)
    throw std::invalid_argument(flag + ": '" + text + "' is not a non-negative number");
  return x;
}

std::vector<std::pair<std::string, double>> ParseJointValues(const std::string& flag,
                                                             const std::string& text) {
  std::vector<std::pair<std::string, double>> out;
  std::istringstream in(text);
  for (std::string item; std::getline(in, item, ',');) {
    const size_t eq = item.find('=');
    char* end = nullptr;
    const double x = eq == std::string::npos ? 0.0 : std::strtod(item.c_str() + eq + 1, &end);
    if (eq == std::string::npos || eq == 0 || end == item.c_str() + eq + 1 || *end != '\0' ||
        !std::isfinite(x)) {
      throw std::invalid_argument(flag + ": '" + item +
                                  "' is not joint=value (value a finite number)");
    }
    out.emplace_back(item.substr(0, eq), x);
  }
  if (out.empty()) throw std::invalid_argument(flag + " needs joint=value[,joint=value...]");
  return out;
}

std::pair<int, int> ParseImageSize(const std::string& flag, const std::string& text) {
  int width = 0, height = 0;
  char extra = 0;
  if (std::sscanf(text.c_str(), "%dx%d%c", &width, &height, &extra) != 2 || width < 16 ||
      height < 16)
    throw std::invalid_argument(flag + ": '" + text + "' is not WIDTHxHEIGHT (each >= 16)");
  return {width, height};
}

void CheckLcmUrl(const std::string& url) {
  if (url.empty()) return;
  for (const char* scheme : {"udpm://", "file://", "memq://", "tcpq://"})
    if (url.rfind(scheme, 0) == 0) return;
  throw std::invalid_argument("--lcm-url '" + url +
                              "' is not an LCM URL; use udpm://239.255.76.67:7667?ttl=0 "
                              "(ttl=0: this machine only; ttl=1 across a network)");
}

}  // namespace marionette::controller
