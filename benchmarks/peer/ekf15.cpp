// Peer for benchmarks/bench_localizer.py: a 15-state EKF core in C++ (Eigen) with a
// measurement history and rewind, fed the same stream as the Localizer.
//
// State (robot_localization's order): x y z roll pitch yaw vx vy vz vroll vpitch vyaw ax ay az.
// Process model: constant velocity and acceleration in the body frame, the 3-D kinematics of
// robot_localization's omnidirectional model (position += R(rpy)(v dt + a dt^2/2), orientation
// += T(rpy) w dt, v += a dt), its Jacobian with the orientation partials, Q = q dt.
// Update: selected state rows, wrapped angle residuals, Mahalanobis gate, Joseph form.
// History: every entry keeps the state it was applied to; a measurement older than the newest
// entry restores the state before the first newer one and re-applies them (as the Localizer).
//
// Input (text, one message a line): kind stamp_ns m idx[m] z[m] R[m*m] gate
//   kind: o (odometry twist), i (imu), p (pose). Output: JSON per-kind timings (ns) on stdout.
//
//   g++ -O2 -DNDEBUG -I/usr/include/eigen3 -o ekf15 ekf15.cpp
#include <Eigen/Dense>
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <deque>
#include <map>
#include <string>
#include <vector>

using Mat15 = Eigen::Matrix<double, 15, 15>;
using Vec15 = Eigen::Matrix<double, 15, 1>;
using MatX = Eigen::MatrixXd;
using VecX = Eigen::VectorXd;

static double wrap(double a) {
  a = std::fmod(a + M_PI, 2.0 * M_PI);
  if (a <= 0.0) a += 2.0 * M_PI;
  return a - M_PI;
}

struct Meas {
  char kind;
  long long stamp;
  std::vector<int> idx;
  VecX z;
  MatX R;
  double gate;
};

struct Entry {
  const Meas* m;
  long long prior_t;
  Vec15 prior_x;
  Mat15 prior_P;
};

class Ekf15 {
 public:
  Ekf15() {
    x.setZero();
    P = Mat15::Identity() * 1e-2;
    P(0, 0) = P(1, 1) = P(5, 5) = 1.0;
    q.setConstant(0.01);
    for (int i = 0; i < 6; ++i) q(i) = 1e-4;
  }
  void predict(double dt) {
    const double cr = std::cos(x(3)), sr = std::sin(x(3)), cp = std::cos(x(4)), sp = std::sin(x(4));
    const double cy = std::cos(x(5)), sy = std::sin(x(5)), tp = sp / cp;
    Eigen::Matrix3d Rot;
    Rot << cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr,
           sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr,
           -sp, cp * sr, cp * cr;
    Eigen::Matrix3d T;
    T << 1.0, sr * tp, cr * tp, 0.0, cr, -sr, 0.0, sr / cp, cr / cp;
    const Eigen::Vector3d v = x.segment<3>(6), w = x.segment<3>(9), a = x.segment<3>(12);
    const Eigen::Vector3d d = v * dt + 0.5 * a * dt * dt;
    Mat15 F = Mat15::Identity();
    F.block<3, 3>(0, 6) = Rot * dt;
    F.block<3, 3>(0, 12) = Rot * (0.5 * dt * dt);
    F.block<3, 3>(3, 9) = T * dt;
    F.block<3, 3>(6, 12) = Eigen::Matrix3d::Identity() * dt;
    // orientation partials of the position (yaw, pitch, roll) and of the attitude rates
    Eigen::Matrix3d dRy, dRp, dRr;
    dRy << -sy * cp, -sy * sp * sr - cy * cr, -sy * sp * cr + cy * sr,
           cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr, 0, 0, 0;
    dRp << -cy * sp, cy * cp * sr, cy * cp * cr, -sy * sp, sy * cp * sr, sy * cp * cr, -cp, -sp * sr, -sp * cr;
    dRr << 0, cy * sp * cr + sy * sr, -cy * sp * sr + sy * cr, 0, sy * sp * cr - cy * sr, -sy * sp * sr - cy * cr,
           0, cp * cr, -cp * sr;
    F.block<3, 1>(0, 3) = dRr * d;
    F.block<3, 1>(0, 4) = dRp * d;
    F.block<3, 1>(0, 5) = dRy * d;
    Eigen::Matrix3d dTr, dTp;
    dTr << 0, cr * tp, -sr * tp, 0, -sr, -cr, 0, cr / cp, -sr / cp;
    const double sec2 = 1.0 / (cp * cp);
    dTp << 0, sr * sec2, cr * sec2, 0, 0, 0, 0, sr * sp * sec2, cr * sp * sec2;
    F.block<3, 1>(3, 3) += dTr * w * dt;
    F.block<3, 1>(3, 4) += dTp * w * dt;
    x.segment<3>(0) += Rot * d;
    x.segment<3>(3) += T * w * dt;
    x.segment<3>(6) += a * dt;
    for (int i = 3; i < 6; ++i) x(i) = wrap(x(i));
    P = F * P * F.transpose();
    P.diagonal() += q * dt;
    P = 0.5 * (P + P.transpose());
  }
  bool update(const Meas& m) {
    const int k = static_cast<int>(m.idx.size());
    MatX H = MatX::Zero(k, 15);
    VecX nu(k);
    for (int r = 0; r < k; ++r) {
      H(r, m.idx[r]) = 1.0;
      nu(r) = m.z(r) - x(m.idx[r]);
      if (m.idx[r] >= 3 && m.idx[r] < 6) nu(r) = wrap(nu(r));
    }
    const MatX PHt = P * H.transpose();
    const MatX S = H * PHt + m.R;
    const Eigen::LLT<MatX> llt(S);
    if (llt.info() != Eigen::Success) return false;
    if (std::isfinite(m.gate) && nu.dot(llt.solve(nu)) > m.gate * m.gate) return false;
    const MatX K = llt.solve(PHt.transpose()).transpose();
    x += K * nu;
    for (int i = 3; i < 6; ++i) x(i) = wrap(x(i));
    const Mat15 IKH = Mat15::Identity() - K * H;
    P = IKH * P * IKH.transpose() + K * m.R * K.transpose();
    P = 0.5 * (P + P.transpose());
    return true;
  }
  Vec15 x;
  Mat15 P;
  Vec15 q;
};

class Localizer15 {
 public:
  explicit Localizer15(long long history_ns, long long max_step_ns) : history_ns_(history_ns), step_ns_(max_step_ns) {}
  void add(const Meas& m) {
    if (!started_) {
      t_ = m.stamp - history_ns_;
      started_ = true;
    }
    if (!hist_.empty() && m.stamp < hist_.back().m->stamp) {
      if (m.stamp < hist_.front().prior_t) return;  // older than the history
      auto it = std::upper_bound(hist_.begin(), hist_.end(), m.stamp,
                                 [](long long s, const Entry& e) { return s < e.m->stamp; });
      const size_t i = static_cast<size_t>(it - hist_.begin());
      ekf_.x = it->prior_x;
      ekf_.P = it->prior_P;
      t_ = it->prior_t;
      hist_.insert(it, Entry{&m, 0, Vec15(), Mat15()});
      for (size_t j = i; j < hist_.size(); ++j) process(hist_[j]);
      ++rewinds;
    } else {
      if (m.stamp < t_) return;
      hist_.push_back(Entry{&m, 0, Vec15(), Mat15()});
      process(hist_.back());
    }
    const long long cutoff = hist_.back().m->stamp - history_ns_;
    while (!hist_.empty() && hist_.front().m->stamp < cutoff) hist_.pop_front();
  }
  long rewinds = 0;
  long accepted = 0;
  Ekf15 ekf_;

 private:
  void process(Entry& e) {
    e.prior_t = t_;
    e.prior_x = ekf_.x;
    e.prior_P = ekf_.P;
    while (t_ < e.m->stamp) {
      const long long end = std::min(e.m->stamp, t_ + step_ns_);
      ekf_.predict((end - t_) * 1e-9);
      t_ = end;
    }
    accepted += ekf_.update(*e.m);
  }
  long long history_ns_, step_ns_, t_ = 0;
  bool started_ = false;
  std::deque<Entry> hist_;
};

int main(int argc, char** argv) {
  if (argc < 2) {
    std::fprintf(stderr, "usage: ekf15 STREAM [repeats]\n");
    return 2;
  }
  const int repeats = argc > 2 ? std::atoi(argv[2]) : 5;
  FILE* f = std::fopen(argv[1], "r");
  if (!f) return 2;
  std::vector<Meas> stream;
  char kind;
  long long stamp;
  int m;
  while (std::fscanf(f, " %c %lld %d", &kind, &stamp, &m) == 3) {
    Meas r{kind, stamp, std::vector<int>(m), VecX(m), MatX(m, m), 0.0};
    for (int j = 0; j < m; ++j) std::fscanf(f, "%d", &r.idx[j]);
    for (int j = 0; j < m; ++j) std::fscanf(f, "%lf", &r.z(j));
    for (int j = 0; j < m * m; ++j) std::fscanf(f, "%lf", &r.R(j / m, j % m));
    std::fscanf(f, "%lf", &r.gate);
    stream.push_back(std::move(r));
  }
  std::fclose(f);
  // per message, the minimum over the repeats (the machine is shared)
  std::vector<long long> best(stream.size(), -1);
  long rewinds = 0, accepted = 0;
  Vec15 final_x;
  for (int rep = 0; rep < repeats; ++rep) {
    Localizer15 loc(500000000LL, 10000000LL);
    for (size_t k = 0; k < stream.size(); ++k) {
      const auto t0 = std::chrono::steady_clock::now();
      loc.add(stream[k]);
      const long long ns = std::chrono::duration_cast<std::chrono::nanoseconds>(
          std::chrono::steady_clock::now() - t0).count();
      if (best[k] < 0 || ns < best[k]) best[k] = ns;
    }
    rewinds = loc.rewinds;
    accepted = loc.accepted;
    final_x = loc.ekf_.x;
  }
  std::map<char, std::vector<long long>> per;
  for (size_t k = 0; k < stream.size(); ++k) per[stream[k].kind].push_back(best[k]);
  per['*'] = best;
  std::printf("{\"rewinds\": %ld, \"accepted\": %ld, \"x\": %.6f, \"y\": %.6f, \"yaw\": %.6f, \"ns\": {",
              rewinds, accepted, final_x(0), final_x(1), final_x(5));
  bool first = true;
  for (auto& [k, v] : per) {
    std::printf("%s\"%c\": [", first ? "" : ", ", k);
    for (size_t j = 0; j < v.size(); ++j) std::printf("%s%lld", j ? "," : "", v[j]);
    std::printf("]");
    first = false;
  }
  std::printf("}}\n");
  return 0;
}
