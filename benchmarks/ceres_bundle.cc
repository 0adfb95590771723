// Ceres reference solve of a jaxba photogrammetric bundle, with jaxba's exact residual
// (CONVENTIONS.md, jaxba._camera.SmacCamera): (U, V, W) = M (X - X0) with
// M = R3(kappa) R2(phi) R1(omega); with x̄ = x_obs - xp, ȳ = y_obs - yp (the MEASURED point),
// r² = x̄² + ȳ²:
//   x = xp - c U / W + dx,  y = yp - c V / W + dy,
//   dx = x̄ (K0 + K1 r² + K2 r⁴ + K3 r⁶) + (1 + P3 r²)(P1 (r² + 2x̄²) + 2 P2 x̄ȳ) - A1 x̄ + A2 ȳ,
//   dy = ȳ (K0 + ...)                   + (1 + P3 r²)(2 P1 x̄ȳ + P2 (r² + 2ȳ²)) + A1 ȳ,
// residual ((x_obs - x) / sx, (y_obs - y) / sy); distances (d_obs - |A - B|) / s.
// Cost ½ Σ r². Fixed parameters by SubsetManifold (a block with none free: constant).
// Levenberg-Marquardt, Ceres' default tolerances (function 1e-6), no robust loss.
// Then the covariance of each camera's IOP block (ceres::Covariance, SPARSE_QR): the IOP
// block is parameterised in scaled units, IOP = s ⊙ scale, and before the covariance the
// scale is set to 1 / (column norm of the Jacobian at the solution), so that SuiteSparseQR's
// rank tolerance sees unit-norm IOP columns; the covariance is scaled back and multiplied
// by σ̂0² = 2 cost / (n_residuals - n_unknowns).
//
// Usage: ceres_bundle EXPORT.txt [LINEAR_SOLVER=SPARSE_SCHUR] [THREADS=1]
// EXPORT.txt is written by benchmarks/block_vs_ceres.py (`export_problem`): sections
// "cameras N" (12 IOPs in SmacCamera.parameter_names order, then 12 free flags),
// "images N" (camera row, X0 Y0 Z0 omega phi kappa in radians, 6 free flags), "points N"
// (X Y Z, 3 free flags), "observations N" (camera image point x y sx sy, mm),
// "distances N" (a b distance sigma). Prints one JSON object on stdout.

#include <sys/resource.h>

#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <string>
#include <utility>
#include <vector>

#include "ceres/ceres.h"

namespace {

constexpr int kIop = 12;
const char* const kIopNames[kIop] = {"xp", "yp", "c",  "K0", "K1", "K2",
                                     "K3", "P1", "P2", "P3", "A1", "A2"};

struct Observation {
  int camera, image, point;
  double x, y, sx, sy;
};

struct Distance {
  int a, b;
  double distance, sigma;
};

struct Block {
  std::vector<double> values;  // n_rows x width, row-major
  std::vector<int> free;       // same shape, 0/1
};

struct Bundle {
  Block cameras, images, points;
  std::vector<int> image_camera;
  std::vector<Observation> observations;
  std::vector<Distance> distances;
  std::vector<double> iop_scale;  // per camera, 12: IOP = s * scale

  bool ReadBlock(FILE* file, const char* name, int width, bool with_camera, Block* block) {
    char section[32];
    int n = 0;
    if (std::fscanf(file, "%31s %d", section, &n) != 2 || std::string(section) != name) {
      return false;
    }
    block->values.resize(n * width);
    block->free.resize(n * width);
    for (int i = 0; i < n; ++i) {
      int camera = 0;
      if (with_camera && std::fscanf(file, "%d", &camera) != 1) return false;
      if (with_camera) image_camera.push_back(camera);
      for (int k = 0; k < width; ++k) {
        if (std::fscanf(file, "%lf", &block->values[i * width + k]) != 1) return false;
      }
      for (int k = 0; k < width; ++k) {
        if (std::fscanf(file, "%d", &block->free[i * width + k]) != 1) return false;
      }
    }
    return true;
  }

  bool Read(const char* path) {
    FILE* file = std::fopen(path, "r");
    if (file == nullptr) return false;
    bool ok = ReadBlock(file, "cameras", kIop, false, &cameras) &&
              ReadBlock(file, "images", 6, true, &images) &&
              ReadBlock(file, "points", 3, false, &points);
    char section[32];
    int n = 0;
    ok = ok && std::fscanf(file, "%31s %d", section, &n) == 2 &&
         std::string(section) == "observations";
    observations.resize(ok ? n : 0);
    for (Observation& o : observations) {
      ok = ok && std::fscanf(file, "%d %d %d %lf %lf %lf %lf", &o.camera, &o.image, &o.point,
                             &o.x, &o.y, &o.sx, &o.sy) == 7;
    }
    ok = ok && std::fscanf(file, "%31s %d", section, &n) == 2 &&
         std::string(section) == "distances";
    distances.resize(ok ? n : 0);
    for (Distance& d : distances) {
      ok = ok && std::fscanf(file, "%d %d %lf %lf", &d.a, &d.b, &d.distance, &d.sigma) == 4;
    }
    std::fclose(file);
    iop_scale.assign(cameras.values.size(), 1.0);
    return ok;
  }
};

// jaxba's image residual; `scale` points at the camera's 12 IOP scales (IOP = s * scale).
struct SmacResidual {
  SmacResidual(const Observation& o, const double* scale)
      : x(o.x), y(o.y), sx(o.sx), sy(o.sy), scale(scale) {}

  template <typename T>
  bool operator()(const T* const s, const T* const eop, const T* const point,
                  T* residual) const {
    using std::cos;
    using std::sin;
    T p[kIop];
    for (int k = 0; k < kIop; ++k) p[k] = s[k] * scale[k];
    const T &xp = p[0], &yp = p[1], &c = p[2];
    const T co = cos(eop[3]), so = sin(eop[3]), cp = cos(eop[4]), sp = sin(eop[4]);
    const T ck = cos(eop[5]), sk = sin(eop[5]);
    const T m[9] = {cp * ck, co * sk + so * sp * ck, so * sk - co * sp * ck,
                    -cp * sk, co * ck - so * sp * sk, so * ck + co * sp * sk,
                    sp, -so * cp, co * cp};
    const T d[3] = {point[0] - eop[0], point[1] - eop[1], point[2] - eop[2]};
    const T u = m[0] * d[0] + m[1] * d[1] + m[2] * d[2];
    const T v = m[3] * d[0] + m[4] * d[1] + m[5] * d[2];
    const T w = m[6] * d[0] + m[7] * d[1] + m[8] * d[2];
    const T xb = x - xp, yb = y - yp;
    const T r2 = xb * xb + yb * yb;
    const T radial = p[3] + r2 * (p[4] + r2 * (p[5] + r2 * p[6]));
    const T p3 = 1.0 + p[9] * r2;
    const T dx = xb * radial + p3 * (p[7] * (r2 + 2.0 * xb * xb) + 2.0 * p[8] * xb * yb) -
                 p[10] * xb + p[11] * yb;
    const T dy = yb * radial + p3 * (2.0 * p[7] * xb * yb + p[8] * (r2 + 2.0 * yb * yb)) +
                 p[10] * yb;
    residual[0] = (x - (xp - c * u / w + dx)) / sx;
    residual[1] = (y - (yp - c * v / w + dy)) / sy;
    return true;
  }

  double x, y, sx, sy;
  const double* scale;
};

struct DistanceResidual {
  explicit DistanceResidual(const Distance& d) : distance(d.distance), sigma(d.sigma) {}

  template <typename T>
  bool operator()(const T* const a, const T* const b, T* residual) const {
    using std::sqrt;
    const T dx = a[0] - b[0], dy = a[1] - b[1], dz = a[2] - b[2];
    residual[0] = (distance - sqrt(dx * dx + dy * dy + dz * dz)) / sigma;
    return true;
  }

  double distance, sigma;
};

// Hold the fixed entries of one parameter block: constant, or a SubsetManifold.
void FixEntries(ceres::Problem* problem, double* values, const int* free, int width) {
  std::vector<int> fixed;
  for (int k = 0; k < width; ++k) {
    if (!free[k]) fixed.push_back(k);
  }
  if (static_cast<int>(fixed.size()) == width) {
    problem->SetParameterBlockConstant(values);
  } else if (!fixed.empty()) {
    problem->SetManifold(values, new ceres::SubsetManifold(width, fixed));
  }
}

void BuildProblem(Bundle* b, ceres::Problem* problem) {
  for (const Observation& o : b->observations) {
    auto* cost = new ceres::AutoDiffCostFunction<SmacResidual, 2, kIop, 6, 3>(
        new SmacResidual(o, &b->iop_scale[kIop * o.camera]));
    problem->AddResidualBlock(cost, nullptr, &b->cameras.values[kIop * o.camera],
                              &b->images.values[6 * o.image], &b->points.values[3 * o.point]);
  }
  for (const Distance& d : b->distances) {
    auto* cost = new ceres::AutoDiffCostFunction<DistanceResidual, 1, 3, 3>(
        new DistanceResidual(d));
    problem->AddResidualBlock(cost, nullptr, &b->points.values[3 * d.a],
                              &b->points.values[3 * d.b]);
  }
  const std::pair<Block*, int> blocks[] = {{&b->cameras, kIop}, {&b->images, 6}, {&b->points, 3}};
  for (const auto& [block, width] : blocks) {
    for (size_t i = 0; i < block->values.size(); i += width) {
      if (problem->HasParameterBlock(&block->values[i])) {
        FixEntries(problem, &block->values[i], &block->free[i], width);
      }
    }
  }
}

// Set camera `row`'s scale to 1 / (Jacobian column norm) of its free IOPs at the current
// values, rescaling the stored s so that the IOPs themselves do not change.
void ScaleToUnitColumns(Bundle* b, ceres::Problem* problem, int row) {
  double* s = &b->cameras.values[kIop * row];
  const int* free = &b->cameras.free[kIop * row];
  double* scale = &b->iop_scale[kIop * row];
  ceres::Problem::EvaluateOptions options;
  options.parameter_blocks = {s};
  options.num_threads = 1;
  ceres::CRSMatrix jacobian;
  problem->Evaluate(options, nullptr, nullptr, nullptr, &jacobian);
  std::vector<double> squares(jacobian.num_cols, 0.0);
  for (size_t k = 0; k < jacobian.values.size(); ++k) {
    squares[jacobian.cols[k]] += jacobian.values[k] * jacobian.values[k];
  }
  int column = 0;  // the tangent space holds the free IOPs in order
  for (int k = 0; k < kIop; ++k) {
    if (!free[k]) continue;
    const double norm = std::sqrt(squares[column++]);
    const double new_scale = scale[k] / norm;  // d r / d s_k = scale_k d r / d IOP_k
    s[k] *= scale[k] / new_scale;
    scale[k] = new_scale;
  }
}

double Seconds(std::chrono::steady_clock::time_point start) {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
}

}  // namespace

int main(int argc, char** argv) {
  if (argc < 2) {
    std::fprintf(stderr, "usage: %s EXPORT.txt [LINEAR_SOLVER] [THREADS]\n", argv[0]);
    return 2;
  }
  const auto start = std::chrono::steady_clock::now();
  Bundle bundle;
  if (!bundle.Read(argv[1])) {
    std::fprintf(stderr, "cannot read bundle export %s\n", argv[1]);
    return 2;
  }
  const std::string linear_solver = argc > 2 ? argv[2] : "SPARSE_SCHUR";
  const int threads = argc > 3 ? std::atoi(argv[3]) : 1;
  ceres::Problem problem;
  BuildProblem(&bundle, &problem);
  const double read_seconds = Seconds(start);

  ceres::Solver::Options options;
  if (!ceres::StringToLinearSolverType(linear_solver, &options.linear_solver_type)) {
    std::fprintf(stderr, "unknown linear solver %s\n", linear_solver.c_str());
    return 2;
  }
  options.minimizer_progress_to_stdout = false;
  options.num_threads = threads;
  options.max_num_iterations = 100;
  ceres::Solver::Summary summary;
  ceres::Solve(options, &problem, &summary);

  const auto covariance_start = std::chrono::steady_clock::now();
  const int n_cameras = static_cast<int>(bundle.cameras.values.size()) / kIop;
  std::vector<std::pair<const double*, const double*>> pairs;
  for (int row = 0; row < n_cameras; ++row) {
    double* s = &bundle.cameras.values[kIop * row];
    if (!problem.HasParameterBlock(s) || problem.IsParameterBlockConstant(s)) continue;
    ScaleToUnitColumns(&bundle, &problem, row);
    pairs.emplace_back(s, s);
  }
  ceres::Covariance::Options covariance_options;
  covariance_options.algorithm_type = ceres::SPARSE_QR;
  covariance_options.num_threads = threads;
  ceres::Covariance covariance(covariance_options);
  const bool covariance_ok = covariance.Compute(pairs, &problem);
  const int redundancy =
      summary.num_residuals_reduced - summary.num_effective_parameters_reduced;
  const double variance_factor = 2.0 * summary.final_cost / redundancy;
  std::string cameras = "[";
  for (int row = 0; row < n_cameras && covariance_ok; ++row) {
    const double* s = &bundle.cameras.values[kIop * row];
    const double* scale = &bundle.iop_scale[kIop * row];
    std::vector<double> block(kIop * kIop);
    covariance.GetCovarianceBlock(s, s, block.data());
    cameras += row ? ", {" : "{";
    for (int k = 0, first = 1; k < kIop; ++k) {
      if (!bundle.cameras.free[kIop * row + k]) continue;
      const double std = scale[k] * std::sqrt(variance_factor * block[k * kIop + k]);
      char entry[160];
      std::snprintf(entry, sizeof entry, "%s\"%s\": {\"value\": %.17g, \"std\": %.17g}",
                    first ? "" : ", ", kIopNames[k], s[k] * scale[k], std);
      cameras += entry;
      first = 0;
    }
    cameras += "}";
  }
  cameras += "]";
  const double covariance_seconds = Seconds(covariance_start);

  rusage usage{};
  getrusage(RUSAGE_SELF, &usage);
  std::printf(
      "{\"solver\": \"ceres %s\", \"linear_solver\": \"%s\", \"threads\": %d, "
      "\"initial_cost\": %.17g, \"final_cost\": %.17g, \"iterations\": %d, "
      "\"successful_iterations\": %d, \"read_seconds\": %.6f, \"solve_seconds\": %.6f, "
      "\"covariance_seconds\": %.6f, \"covariance_ok\": %s, \"redundancy\": %d, "
      "\"sigma0_squared\": %.17g, \"converged\": %s, \"termination\": \"%s\", "
      "\"cameras\": %s, \"peak_rss_mib\": %.1f}\n",
      CERES_VERSION_STRING, linear_solver.c_str(), threads, summary.initial_cost,
      summary.final_cost, summary.num_successful_steps + summary.num_unsuccessful_steps,
      summary.num_successful_steps, read_seconds, summary.total_time_in_seconds,
      covariance_seconds, covariance_ok ? "true" : "false", redundancy, variance_factor,
      summary.termination_type == ceres::CONVERGENCE ? "true" : "false",
      ceres::TerminationTypeToString(summary.termination_type), cameras.c_str(),
      usage.ru_maxrss / 1024.0);
  return 0;
}
