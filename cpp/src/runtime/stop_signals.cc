#include "marionette/runtime/stop_signals.h"

#include <pthread.h>

#include <csignal>
#include <initializer_list>

namespace marionette::runtime {

void RestoreStopSignals() {
  sigset_t stop;
  sigemptyset(&stop);
  for (const int signal : {SIGINT, SIGTERM}) {
    sigaddset(&stop, signal);
    struct sigaction current {};
    if (sigaction(signal, nullptr, &current) == 0 && current.sa_handler == SIG_IGN) {
      struct sigaction fallback {};
      fallback.sa_handler = SIG_DFL;
      sigemptyset(&fallback.sa_mask);
      sigaction(signal, &fallback, nullptr);
    }
  }
  pthread_sigmask(SIG_UNBLOCK, &stop, nullptr);
}

}  // namespace marionette::runtime
