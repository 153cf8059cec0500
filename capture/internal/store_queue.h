// Internal to capture/: storage of accepted frames on its own thread, in order, through the
// resumable ImageSet writer, so PNG encoding and fsync do not pace the projector. Push blocks
// while `capacity` images wait; a storage error is rethrown by the next Push or by Finish.
#pragma once

#include <atomic>
#include <condition_variable>
#include <deque>
#include <exception>
#include <mutex>
#include <thread>
#include <utility>

#include <opencv2/core.hpp>

#include "core/image_set.h"

namespace slshadow::capture::internal {

// Storage on its own thread, in order, through the resumable writer.
class StoreQueue {
 public:
  StoreQueue(ResumableImageSetWriter& writer, size_t capacity)
      : writer_(writer), capacity_(capacity) {
    thread_ = std::thread([this] { Run(); });
  }
  ~StoreQueue() {
    try {
      Finish();
    } catch (...) {}
  }
  void Push(ImageRecord record, cv::Mat image) {
    std::unique_lock<std::mutex> lock(mutex_);
    space_.wait(lock, [&] { return queue_.size() < capacity_ || error_; });
    if (error_) std::rethrow_exception(error_);
    queue_.push_back({std::move(record), std::move(image)});
    ready_.notify_one();
  }
  // Waits until everything queued is stored; rethrows a storage error.
  void Finish() {
    {
      std::lock_guard<std::mutex> lock(mutex_);
      done_ = true;
      ready_.notify_one();
    }
    if (thread_.joinable()) thread_.join();
    if (error_) {
      auto e = error_;
      error_ = nullptr;
      std::rethrow_exception(e);
    }
  }
  int stored() const { return stored_.load(); }

 private:
  void Run() {
    for (;;) {
      std::pair<ImageRecord, cv::Mat> item;
      {
        std::unique_lock<std::mutex> lock(mutex_);
        ready_.wait(lock, [&] { return !queue_.empty() || done_; });
        if (queue_.empty()) return;
        item = std::move(queue_.front());
        queue_.pop_front();
      }
      try {
        writer_.Add(std::move(item.first), item.second);
        ++stored_;
      } catch (...) {
        std::lock_guard<std::mutex> lock(mutex_);
        error_ = std::current_exception();
        queue_.clear();
        space_.notify_all();
        return;
      }
      space_.notify_all();
    }
  }
  ResumableImageSetWriter& writer_;
  size_t capacity_;
  std::deque<std::pair<ImageRecord, cv::Mat>> queue_;
  std::mutex mutex_;
  std::condition_variable ready_, space_;
  std::exception_ptr error_;
  bool done_ = false;
  std::atomic<int> stored_{0};
  std::thread thread_;
};

}  // namespace slshadow::capture::internal
