// Robust straight-line fit used wherever an error or residual trend is measured: the long-gap
// drift rate (offline.h, the paper's Fig. 7/8 measure) and the discovery statistics.
#ifndef ESG_ESTIMATOR_LINE_FIT_H_
#define ESG_ESTIMATOR_LINE_FIT_H_

#include <vector>

namespace esg::estimator {

// Least-squares line y = a + b t with a robust second pass (points beyond 5 scaled MADs of the
// first fit's residuals dropped and the line refitted); returns {a, b}, the residual standard
// deviation of the points used and their number.
struct RobustLine {
  double intercept = 0.0;
  double slope = 0.0;
  double residual_sigma = 0.0;
  int used = 0;
};
RobustLine FitRobustLine(const std::vector<double>& t, const std::vector<double>& y);

}  // namespace esg::estimator

#endif  // ESG_ESTIMATOR_LINE_FIT_H_
