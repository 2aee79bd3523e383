#include "dcslam/joining/parallel_tasks.hpp"

#include <algorithm>
#include <atomic>
#include <cstddef>
#include <exception>
#include <limits>
#include <thread>

namespace dcslam {

namespace {

// The threads that the outermost run_tasks() may still start, shared by every call nested in
// its tasks: a thread that has run out of tasks gives its place back, so a nested call can use
// it while a long task of the outer call is still running.
thread_local std::atomic<int>* spare_threads = nullptr;

int claim(std::atomic<int>& spare, int wanted) {
  int available = spare.load();
  int taken = 0;
  do {
    taken = std::min(available, wanted);
  } while (taken > 0 && !spare.compare_exchange_weak(available, available - taken));
  return std::max(taken, 0);
}

}  // namespace

int estimate_thread_count(int configured) {
  if (configured > 0) return configured;
  return std::max(1, static_cast<int>(std::thread::hardware_concurrency()));
}

void run_tasks(const std::vector<std::function<void()>>& tasks, int threads) {
  if (tasks.empty()) return;
  std::atomic<int> outermost{std::max(threads, 1) - 1};
  std::atomic<int>& spare = spare_threads ? *spare_threads : outermost;
  std::atomic<int>* const callers = spare_threads;
  spare_threads = &spare;
  std::vector<std::exception_ptr> errors(tasks.size());
  std::atomic<std::size_t> next{0};
  const auto work = [&] {
    for (std::size_t k = next++; k < tasks.size(); k = next++) {
      try {
        tasks[k]();
      } catch (...) {
        errors[k] = std::current_exception();
      }
    }
  };
  const int helpers = claim(spare, static_cast<int>(std::min<std::size_t>(tasks.size() - 1, std::numeric_limits<int>::max())));
  std::vector<std::thread> pool;
  pool.reserve(static_cast<std::size_t>(helpers));
  for (int k = 0; k < helpers; ++k) {
    try {
      pool.emplace_back([&] {
        spare_threads = &spare;
        work();
        ++spare;
      });
    } catch (...) {  // no thread to be had (std::system_error): the others do the work
      ++spare;
    }
  }
  work();
  for (std::thread& thread : pool) thread.join();
  spare_threads = callers;
  for (const std::exception_ptr& error : errors) {
    if (error) std::rethrow_exception(error);
  }
}

void run_for_each(std::size_t count, int threads, const std::function<void(std::size_t)>& task) {
  std::vector<std::function<void()>> tasks;
  tasks.reserve(count);
  for (std::size_t k = 0; k < count; ++k) tasks.emplace_back([&task, k] { task(k); });
  run_tasks(tasks, threads);
}

}  // namespace dcslam
