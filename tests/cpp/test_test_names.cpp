#include <string>

#include <gtest/gtest.h>

namespace dcslam {
namespace {

// gtest_discover_tests puts each parameter's printed value into the CTest name. A parameter
// type without a PrintTo is printed as its raw bytes, padding included, which differ from
// build to build and are not text: every parameter must print as readable text.
TEST(TestNames, EveryParameterPrintsAsReadableText) {
  const ::testing::UnitTest& unit = *::testing::UnitTest::GetInstance();
  int parameterized = 0;
  for (int s = 0; s < unit.total_test_suite_count(); ++s) {
    const ::testing::TestSuite& suite = *unit.GetTestSuite(s);
    for (int t = 0; t < suite.total_test_count(); ++t) {
      const ::testing::TestInfo& info = *suite.GetTestInfo(t);
      if (!info.value_param()) continue;
      ++parameterized;
      const std::string value = info.value_param();
      const std::string name = std::string(suite.name()) + "." + info.name();
      EXPECT_EQ(value.find("-byte object"), std::string::npos) << name << ": " << value;
      for (const char c : value) {
        EXPECT_TRUE(c >= 0x20 && c < 0x7f) << name << ": byte " << static_cast<int>(c);
      }
    }
  }
  EXPECT_GT(parameterized, 0);
}

}  // namespace
}  // namespace dcslam
