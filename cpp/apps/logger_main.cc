// marionette-logger: every message of an LCM URL written to an LCM log file, none dropped behind
// a reader that the machine keeps off the CPU.
//
// The file is lcm-logger's format, written by liblcm's own lcm_eventlog, so every LCM tool
// (lcm-logplayer, lcm-spy, lcm.EventLog) reads it. What differs from lcm-logger is the queue
// between LCM's reader thread and the handler: lcm-logger keeps LCM's default of 30 messages for
// its one subscription, and LCM discards, silently, every message that arrives while 30 wait.
// On a busy machine a logger off the CPU for 30 ms of 1 kHz traffic lost messages that way with
// the kernel dropping none (a footstep plan missing from a grasp-walk log). Here the queue has no
// bound: LCM's receive buffer grows instead, and what arrived is written once the handler runs.
#include <lcm/eventlog.h>
#include <lcm/lcm.h>

#include <cerrno>
#include <csignal>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <ctime>
#include <optional>
#include <regex>
#include <stdexcept>
#include <string>

#include "marionette/runtime/stop_signals.h"

namespace {

constexpr const char* kUsage = R"(usage: marionette-logger -f FILE [--lcm-url URL] [--exclude REGEX]

Writes every LCM message on URL to FILE (LCM's log format: lcm-logplayer, lcm-spy and
lcm.EventLog read it) until SIGINT or SIGTERM, then prints how many it wrote. No message that
reached the process is dropped, however long it waits for the CPU.

  -f, --file FILE    the log to write (replaced if it exists)
  --lcm-url URL      LCM URL (default: $LCM_DEFAULT_URL, else LCM's default)
  --exclude REGEX    channels not to write (ECMAScript regex searched in the channel name),
                     e.g. '^CAMERA_' to leave camera frames out
  -h, --help         this text
)";

constexpr int kWaitMs = 100;          // the longest wait for a message before checking for a stop
constexpr int64_t kFlushUs = 100000;  // written data reaches the file at least this often

struct Options {
  std::string file;
  std::string lcm_url;
  std::optional<std::regex> exclude;
  bool help = false;
};

Options ParseOptions(int argc, char** argv) {
  Options o;
  const auto value = [&](int& i) -> std::string {
    if (i + 1 >= argc) throw std::invalid_argument(std::string(argv[i]) + " needs a value");
    return argv[++i];
  };
  for (int i = 1; i < argc; ++i) {
    std::string a = argv[i];
    std::optional<std::string> inline_value;  // --flag=value
    if (const auto eq = a.find('='); a.rfind("--", 0) == 0 && eq != std::string::npos) {
      inline_value = a.substr(eq + 1);
      a = a.substr(0, eq);
    }
    const auto take = [&]() { return inline_value ? *inline_value : value(i); };
    if (a == "-h" || a == "--help") {
      o.help = true;
    } else if (a == "-f" || a == "--file") {
      o.file = take();
    } else if (a == "--lcm-url") {
      o.lcm_url = take();
    } else if (a == "--exclude") {
      const std::string pattern = take();
      try {
        o.exclude.emplace(pattern, std::regex::ECMAScript | std::regex::optimize);
      } catch (const std::regex_error& e) {
        throw std::invalid_argument("--exclude " + pattern + " is not a regex: " + e.what());
      }
    } else {
      throw std::invalid_argument("unknown option " + a);
    }
  }
  if (!o.help && o.file.empty()) throw std::invalid_argument("-f FILE is required");
  return o;
}

volatile std::sig_atomic_t g_stop = 0;
void OnSignal(int) { g_stop = 1; }

struct Logger {
  lcm_eventlog_t* log = nullptr;
  const std::optional<std::regex>* exclude = nullptr;
  int64_t written = 0;
  int64_t excluded = 0;
  int write_errno = 0;  // the first failed write's errno (0: none)
};

void OnMessage(const lcm_recv_buf_t* rbuf, const char* channel, void* user) {
  auto* logger = static_cast<Logger*>(user);
  if (*logger->exclude && std::regex_search(channel, **logger->exclude)) {
    ++logger->excluded;
    return;
  }
  lcm_eventlog_event_t event{};
  event.timestamp = rbuf->recv_utime;
  event.channellen = static_cast<int32_t>(std::strlen(channel));
  event.datalen = static_cast<int32_t>(rbuf->data_size);
  event.channel = const_cast<char*>(channel);
  event.data = rbuf->data;
  if (lcm_eventlog_write_event(logger->log, &event) != 0) {
    if (logger->write_errno == 0) logger->write_errno = errno != 0 ? errno : EIO;
    g_stop = 1;
    return;
  }
  ++logger->written;
}

int64_t NowUs() {
  timespec ts{};
  clock_gettime(CLOCK_MONOTONIC, &ts);
  return static_cast<int64_t>(ts.tv_sec) * 1000000 + ts.tv_nsec / 1000;
}

}  // namespace

int main(int argc, char** argv) {
  marionette::runtime::RestoreStopSignals();  // before LCM's thread: it inherits the mask
  Options options;
  try {
    options = ParseOptions(argc, argv);
  } catch (const std::exception& e) {
    std::fprintf(stderr, "marionette-logger: %s (see marionette-logger --help)\n", e.what());
    return 2;
  }
  if (options.help) {
    std::fputs(kUsage, stdout);
    return 0;
  }
  lcm_t* lcm = lcm_create(options.lcm_url.empty() ? nullptr : options.lcm_url.c_str());
  if (lcm == nullptr) {
    std::fprintf(stderr, "marionette-logger: cannot open LCM URL '%s' (check --lcm-url)\n",
                 options.lcm_url.c_str());
    return 1;
  }
  Logger logger;
  logger.exclude = &options.exclude;
  logger.log = lcm_eventlog_create(options.file.c_str(), "w");
  if (logger.log == nullptr) {
    std::fprintf(stderr, "marionette-logger: cannot write %s: %s\n", options.file.c_str(),
                 std::strerror(errno));
    lcm_destroy(lcm);
    return 1;
  }
  lcm_subscription_t* subscription = lcm_subscribe(lcm, ".*", OnMessage, &logger);
  lcm_subscription_set_queue_capacity(subscription, 0);  // 0: no bound (lcm.h)
  std::signal(SIGINT, OnSignal);
  std::signal(SIGTERM, OnSignal);

  int64_t flushed_us = NowUs();
  int receive_errno = 0;  // a failed receive's errno (0: none; a stop signal's EINTR is none)
  while (!g_stop) {
    if (lcm_handle_timeout(lcm, kWaitMs) < 0 && !g_stop && errno != EINTR) {
      receive_errno = errno != 0 ? errno : EIO;
      break;
    }
    if (const int64_t now = NowUs(); now - flushed_us >= kFlushUs) {
      std::fflush(logger.log->f);
      flushed_us = now;
    }
  }
  // What LCM received before the stop is written too.
  while (logger.write_errno == 0 && lcm_handle_timeout(lcm, 0) > 0) {
  }
  lcm_unsubscribe(lcm, subscription);
  lcm_eventlog_destroy(logger.log);
  lcm_destroy(lcm);
  if (receive_errno != 0) {
    std::fprintf(stderr, "marionette-logger: receiving from LCM failed after %lld messages: %s\n",
                 static_cast<long long>(logger.written), std::strerror(receive_errno));
    return 1;
  }
  if (logger.write_errno != 0) {
    std::fprintf(stderr, "marionette-logger: writing %s failed after %lld messages: %s\n",
                 options.file.c_str(), static_cast<long long>(logger.written),
                 std::strerror(logger.write_errno));
    return 1;
  }
  std::printf("marionette-logger: %lld messages written to %s (%lld on excluded channels)\n",
              static_cast<long long>(logger.written), options.file.c_str(),
              static_cast<long long>(logger.excluded));
  return 0;
}
