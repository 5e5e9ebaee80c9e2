#pragma once
/// The command-line values marionette-controller and marionette-sim read the same way; each throws
/// std::invalid_argument with one line naming the flag and what it takes.

#include <string>
#include <utility>
#include <vector>

namespace marionette::controller {

/// A finite number >= 0 given to `flag`.
double ParseNonNegative(const std::string& flag, const std::string& text);
/// "name=value,name=value" (e.g. --encoder-offsets) -> pairs, values finite.
std::vector<std::pair<std::string, double>> ParseJointValues(const std::string& flag,
                                                             const std::string& text);
/// "WIDTHxHEIGHT" (--camera-size), each at least 16.
std::pair<int, int> ParseImageSize(const std::string& flag, const std::string& text);
/// Throws unless `url` is empty or an LCM URL (udpm://, file://, memq://, tcpq://).
void CheckLcmUrl(const std::string& url);

}  // namespace marionette::controller
