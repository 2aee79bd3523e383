#pragma once
// Independent computations of estimate() run side by side (SlamConfig::estimate_threads): the
// associations of a join's candidate versions (DecidingJoin::associate), the rest of the fold
// carried through each version of a weak fold join (DCSlam::decide_by_rest_of_fold), the
// column blocks of a join's result (JoinFill::fill_rest), and the re-linearisation pass's
// leaves and disjoint subtrees (JoinTree::relinearise).
#include <cstddef>
#include <functional>
#include <vector>

namespace dcslam {

// The threads `configured` asks for: 0 is every hardware thread (at least one).
int estimate_thread_count(int configured);

// Runs every task once, on up to `threads` threads, the calling one included. Each task must
// write only what is its own, so that what the tasks compute is the same for every thread
// count and order. A call from inside a task shares the outermost call's threads (`threads` is
// then not used): it starts only those that no other task is using, so nesting never
// multiplies the threads. Every task runs even when one throws; the exception of the first
// task (in the list's order) that threw is then rethrown.
void run_tasks(const std::vector<std::function<void()>>& tasks, int threads);
// run_tasks() of task(0), ..., task(count - 1).
void run_for_each(std::size_t count, int threads, const std::function<void(std::size_t)>& task);

}  // namespace dcslam
