// A one-line progress bar with phase, percentage and ETA on stderr; safe to update from worker threads.
#pragma once

#include <chrono>
#include <cstdio>
#include <exception>
#include <mutex>
#include <string>

#include <unistd.h>

namespace svo::tools {

class ProgressBar {
 public:
  explicit ProgressBar(std::string phase) : phase_(std::move(phase)), tty_(::isatty(2)) {}
  // Unwinding from an error, the bar ends where it was (a terminal gets its line ended), never at 100%.
  ~ProgressBar() {
    if (std::uncaught_exceptions() == 0) {
      finish();
      return;
    }
    std::lock_guard lock(mutex_);
    if (tty_ && !done_) std::fputc('\n', stderr);
    done_ = true;
  }

  void update(double fraction) {
    std::lock_guard lock(mutex_);
    const auto now = std::chrono::steady_clock::now();
    // Redraw at most every 100 ms on a terminal, every 10% in a log.
    if (tty_ ? now - last_ < std::chrono::milliseconds(100) : fraction < nextLogged_) return;
    last_ = now;
    nextLogged_ = fraction + 0.1;
    draw(fraction, now);
  }
  // Shown after the ETA from the next redraw on ("12/64 cells, 3.1M voxels").
  void setDetail(std::string detail) {
    std::lock_guard lock(mutex_);
    detail_ = std::move(detail);
  }
  void finish() {
    std::lock_guard lock(mutex_);
    if (done_) return;
    done_ = true;
    draw(1.0, std::chrono::steady_clock::now());
    if (tty_) std::fputc('\n', stderr);
  }

 private:
  void draw(double fraction, std::chrono::steady_clock::time_point now) {
    const double elapsed = std::chrono::duration<double>(now - start_).count();
    const double eta = fraction > 0.01 ? elapsed * (1.0 - fraction) / fraction : 0.0;
    constexpr int kWidth = 30;
    const int filled = int(fraction * kWidth);
    std::fprintf(stderr, "%s%-8s [%s%s] %5.1f%%  %6.1fs elapsed  ETA %5.1fs%s%s%s", tty_ ? "\r" : "",
                 phase_.c_str(), std::string(filled, '#').c_str(), std::string(kWidth - filled, '.').c_str(),
                 fraction * 100.0, elapsed, eta, detail_.empty() ? "" : "  ", detail_.c_str(),
                 tty_ ? "" : "\n");
    std::fflush(stderr);
  }

  std::string phase_, detail_;
  bool tty_;
  bool done_ = false;
  double nextLogged_ = 0.0;
  std::mutex mutex_;
  std::chrono::steady_clock::time_point start_ = std::chrono::steady_clock::now(), last_{};
};

}  // namespace svo::tools
