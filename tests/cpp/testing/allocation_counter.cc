// Interposes the allocation functions and pthread_mutex_lock for the whole test executable and
// counts the calls made by a thread while it is armed. Forwards to glibc's own entry points.
#include "allocation_counter.h"

#include <dlfcn.h>
#include <malloc.h>
#include <pthread.h>

#include <cerrno>
#include <cstddef>

extern "C" {
void* __libc_malloc(size_t);
void* __libc_calloc(size_t, size_t);
void* __libc_realloc(void*, size_t);
void* __libc_memalign(size_t, size_t);
void __libc_free(void*);
}

namespace {
thread_local int armed = 0;
thread_local int64_t allocations = 0;
thread_local int64_t locks = 0;
inline void Count() {
  if (armed > 0) ++allocations;
}
}  // namespace

extern "C" {
void* malloc(size_t size) {
  Count();
  return __libc_malloc(size);
}
void* calloc(size_t n, size_t size) {
  Count();
  return __libc_calloc(n, size);
}
void* realloc(void* p, size_t size) {
  Count();
  return __libc_realloc(p, size);
}
void* memalign(size_t alignment, size_t size) {
  Count();
  return __libc_memalign(alignment, size);
}
void* aligned_alloc(size_t alignment, size_t size) {
  Count();
  return __libc_memalign(alignment, size);
}
int posix_memalign(void** out, size_t alignment, size_t size) {
  Count();
  void* p = __libc_memalign(alignment, size);
  if (p == nullptr) return ENOMEM;
  *out = p;
  return 0;
}
void free(void* p) { __libc_free(p); }

int pthread_mutex_lock(pthread_mutex_t* mutex) {
  using LockFn = int (*)(pthread_mutex_t*);
  static LockFn real = reinterpret_cast<LockFn>(dlsym(RTLD_NEXT, "pthread_mutex_lock"));
  if (armed > 0) ++locks;
  return real(mutex);
}
}

namespace marionette::testing {

ScopedAllocationCounter::ScopedAllocationCounter()
    : allocations_at_start_(::allocations), locks_at_start_(::locks) {
  ++armed;
}
ScopedAllocationCounter::~ScopedAllocationCounter() { --armed; }
int64_t ScopedAllocationCounter::allocations() const {
  return ::allocations - allocations_at_start_;
}
int64_t ScopedAllocationCounter::locks() const { return ::locks - locks_at_start_; }

}  // namespace marionette::testing
