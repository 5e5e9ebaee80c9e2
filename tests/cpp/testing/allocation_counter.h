#pragma once
/// Counts heap allocations and mutex locks made by the calling thread while a
/// ScopedAllocationCounter is alive. Link allocation_counter.cc into the test executable: it
/// interposes malloc & co. and pthread_mutex_lock (Drake's *_limit_malloc_test idea).

#include <cstdint>

namespace marionette::testing {

class ScopedAllocationCounter {
 public:
  ScopedAllocationCounter();
  ~ScopedAllocationCounter();
  int64_t allocations() const;  ///< malloc/calloc/realloc/aligned allocations so far
  int64_t locks() const;        ///< pthread_mutex_lock calls so far

 private:
  int64_t allocations_at_start_;
  int64_t locks_at_start_;
};

}  // namespace marionette::testing
