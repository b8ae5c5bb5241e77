// Counting heap allocations in the C++ tests (test_controller.cpp, test_isolation.cpp): include in ONE translation
// unit of a test executable (it defines operator new/delete and the malloc family). Count a region with
//   g_allocations = 0; g_counting = true; ...; g_counting = false;   then read g_allocations.
// g_trace (set from the environment by the test, e.g. TRACE_ALLOC): the first allocation counted prints its stack
// and aborts, to find where a real-time path allocates.
#pragma once

#include <atomic>
#include <cstddef>
#include <cstdlib>
#include <execinfo.h>
#include <new>

static std::atomic<long> g_allocations{0};
static std::atomic<bool> g_counting{false};
static bool g_trace = false;

#if defined(__SANITIZE_ADDRESS__)
// Under AddressSanitizer (REFLEXARM_SANITIZE, g++ defines __SANITIZE_ADDRESS__) the replacement below cannot
// work: ASan owns malloc/free and operator new/delete, so a block from __libc_malloc freed by ASan's free
// (or the other way round) is a crash. ASan calls an installed malloc hook for every allocation it serves
// (malloc, calloc, realloc, aligned/posix_memalign, operator new and new[]): count there instead, so the
// no-heap-allocation checks keep their meaning in the sanitizer build.
// (the sanitizer interface, declared here: g++ 12 ships libasan but not <sanitizer/*.h>)
extern "C" int __sanitizer_install_malloc_and_free_hooks(void (*)(const volatile void *, std::size_t),
                                                         void (*)(const volatile void *));
extern "C" void __sanitizer_print_stack_trace();
static void countingMallocHook(const volatile void *, std::size_t)
{
  if (g_counting.load(std::memory_order_relaxed))
  {
    g_allocations.fetch_add(1, std::memory_order_relaxed);
    if (g_trace)
    {
      g_counting = false;
      __sanitizer_print_stack_trace();
      std::abort();
    }
  }
}
static void countingFreeHook(const volatile void *) {}
[[maybe_unused]] static const int g_hooks_installed =
  __sanitizer_install_malloc_and_free_hooks(countingMallocHook, countingFreeHook);
#else
extern "C" void * __libc_malloc(std::size_t);
extern "C" void * __libc_calloc(std::size_t, std::size_t);
extern "C" void * __libc_realloc(void *, std::size_t);

// one allocation seen: counted while counting (with g_trace: its stack printed, then abort)
static void countAllocation()
{
  if (!g_counting.load(std::memory_order_relaxed))
    return;
  g_allocations.fetch_add(1, std::memory_order_relaxed);
  if (g_trace)
  {
    g_counting = false;
    void * frames[40];
    const int k = backtrace(frames, 40);
    backtrace_symbols_fd(frames, k, 2);
    std::abort();
  }
}

void * operator new(std::size_t size)
{
  countAllocation();
  if (void * p = __libc_malloc(size ? size : 1))
    return p;
  throw std::bad_alloc();
}
void * operator new[](std::size_t size)
{
  return operator new(size);
}
void operator delete(void * p) noexcept
{
  std::free(p);
}
void operator delete[](void * p) noexcept
{
  std::free(p);
}
void operator delete(void * p, std::size_t) noexcept
{
  std::free(p);
}
void operator delete[](void * p, std::size_t) noexcept
{
  std::free(p);
}

// Eigen (and C code) allocate through malloc, not operator new: count the malloc family too (glibc).
extern "C" void * malloc(std::size_t size)
{
  countAllocation();
  return __libc_malloc(size);
}
extern "C" void * calloc(std::size_t n, std::size_t size)
{
  countAllocation();
  return __libc_calloc(n, size);
}
extern "C" void * realloc(void * ptr, std::size_t size)
{
  countAllocation();
  return __libc_realloc(ptr, size);
}
#endif // __SANITIZE_ADDRESS__
