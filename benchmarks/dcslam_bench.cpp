// dcslam_bench: the native benchmark. Later issues add the EKF / D&C runs.
#include <iostream>

int main() {
  std::cout << "dcslam_bench: no benchmarks yet\n";
  return 0;
}
