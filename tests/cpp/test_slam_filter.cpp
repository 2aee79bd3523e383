#include <gtest/gtest.h>

#include "dcslam/core/slam_filter.hpp"

namespace dcslam {
namespace {

// With user-given ids an id can be merged away and come back: 7 into 5, then 5 into 7. The
// second merge makes 7 live again, so its old alias goes and no cycle can form.
TEST(IdAliases, AMergedIdThatComesBackCannotCloseACycle) {
  IdAliases aliases;
  add_alias(aliases, 7, 5);
  EXPECT_EQ(follow_aliases(aliases, 7), 5);
  add_alias(aliases, 5, 7);
  EXPECT_EQ(follow_aliases(aliases, 5), 7);
  EXPECT_EQ(follow_aliases(aliases, 7), 7);
  add_alias(aliases, 3, -1);
  add_alias(aliases, 9, 9);  // a feature merged into itself records nothing
  EXPECT_EQ(follow_aliases(aliases, 3), -1);
  EXPECT_EQ(aliases.count(9), 0u);
  // Chains are followed to their end.
  add_alias(aliases, 1, 2);
  add_alias(aliases, 2, 4);
  EXPECT_EQ(follow_aliases(aliases, 1), 4);
}

}  // namespace
}  // namespace dcslam
