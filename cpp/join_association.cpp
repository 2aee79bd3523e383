#include "dcslam/join_association.hpp"

#include "dcslam/errors.hpp"

namespace dcslam {

JoinAssociationResult associate_maps(const JoinFrame&, const JoinOptions& options) {
  throw InvalidArgument(std::string("SlamConfig.join_association: '") +
                        to_string(options.association) + "' is not available yet");
}

}  // namespace dcslam
