#include "tests/capture/dlpc350_emulator.h"

#include <algorithm>

namespace slshadow::capture::testing {
using dlpc350::Report;

void Dlpc350Emulator::Receive(const Report& report) {
  if (expected_ == 0) {
    partial_ = Request{};
    partial_.flags = report[0];
    partial_.seq = report[1];
    expected_ = report[2] | size_t(report[3]) << 8;
    pending_.assign(report.begin() + 4, report.begin() + 4 + std::min<size_t>(expected_, 60));
  } else {
    const size_t n = std::min(expected_ - pending_.size(), dlpc350::kReportSize);
    pending_.insert(pending_.end(), report.begin(), report.begin() + static_cast<long>(n));
  }
  partial_.reports.push_back(report);
  if (pending_.size() < expected_) return;
  expected_ = 0;
  if (pending_.size() >= 2) {
    partial_.command = static_cast<uint16_t>(pending_[0] | pending_[1] << 8);
    partial_.data.assign(pending_.begin() + 2, pending_.end());
  }
  log.push_back(partial_);
  Handle(partial_);
}

bool Dlpc350Emulator::PopReply(Report* report) {
  if (replies_.empty()) return false;
  *report = replies_.front();
  replies_.pop_front();
  return true;
}

void Dlpc350Emulator::Reply(const Request& request, uint8_t flags,
                            const std::vector<uint8_t>& data) {
  if (silent || !(request.flags & dlpc350::kFlagReply)) return;
  Report r{};
  r[0] = flags;
  r[1] = static_cast<uint8_t>(wrong_seq ? request.seq + 1 : request.seq);
  r[2] = static_cast<uint8_t>(data.size() & 0xFF);
  r[3] = static_cast<uint8_t>(data.size() >> 8);
  size_t at = std::min<size_t>(data.size(), 60);
  std::copy(data.begin(), data.begin() + static_cast<long>(at), r.begin() + 4);
  auto& queue = hold ? held_ : replies_;
  queue.push_back(r);
  while (at < data.size()) {
    Report next{};
    const size_t n = std::min(data.size() - at, dlpc350::kReportSize);
    std::copy(data.begin() + static_cast<long>(at), data.begin() + static_cast<long>(at + n),
              next.begin());
    queue.push_back(next);
    at += n;
  }
}

void Dlpc350Emulator::ReleaseHeld() {
  replies_.insert(replies_.end(), held_.begin(), held_.end());
  held_.clear();
}

void Dlpc350Emulator::Handle(const Request& q) {
  const bool read = q.flags & dlpc350::kFlagRead;
  if (q.command == nack_command)
    return Reply(q, static_cast<uint8_t>(q.flags | dlpc350::kFlagNack), {});
  auto need = [&](size_t n) { return q.data.size() == n; };
  using namespace dlpc350;
  if (read) {
    switch (q.command) {
      case kDisplayMode:
        return Reply(q, q.flags, {display_mode});
      case kSequenceControl:
        return Reply(q, q.flags, {sequence_control});
      case kVersion:
        return Reply(q, q.flags, version);
      case kValidate:
        if (busy_polls > 0) {
          --busy_polls;
          return Reply(q, q.flags, {0x80});
        }
        return Reply(q, q.flags, {validation_status});
      default:
        return Reply(q, static_cast<uint8_t>(q.flags | kFlagNack), {});
    }
  }
  bool ok = true;
  switch (q.command) {
    case kDisplayMode:
      ok = need(1) && q.data[0] <= 1;
      if (ok) display_mode = q.data[0];
      break;
    case kSequenceControl:
      ok = need(1) && q.data[0] <= 2;
      if (ok) sequence_control = q.data[0];
      if (ok && on_sequence_control) on_sequence_control(q.data[0]);
      break;
    case kPatternSource:
      ok = need(1) && (q.data[0] == 0 || q.data[0] == 3);
      break;
    case kPatternTrigger:
      ok = need(1) && q.data[0] <= 4;
      break;
    case kExposure:
      ok = need(8);
      if (ok) {
        exposure_us = uint32_t(q.data[0]) | uint32_t(q.data[1]) << 8 | uint32_t(q.data[2]) << 16 |
                      uint32_t(q.data[3]) << 24;
        frame_period_us = uint32_t(q.data[4]) | uint32_t(q.data[5]) << 8 |
                          uint32_t(q.data[6]) << 16 | uint32_t(q.data[7]) << 24;
      }
      break;
    case kPatternConfig:
      ok = need(4);
      if (ok) pattern_config = q.data;
      break;
    case kTrigOut1:
      ok = need(3);
      if (ok) trig_out1 = q.data;
      break;
    case kTrigOut2:
      ok = need(2);
      break;
    case kValidate:
      ok = need(1);
      break;
    case kMailboxOpen:
      ok = need(1) && q.data[0] <= 3;
      if (ok) mailbox = q.data[0];
      break;
    case kMailboxAddress:
      ok = need(1) && q.data[0] < 128;
      if (ok) mailbox_address = q.data[0];
      break;
    case kMailboxData:
      ok = mailbox == 1 || mailbox == 2;
      if (mailbox == 1) image_lut = q.data;
      if (mailbox == 2) pattern_lut = q.data;
      break;
    default:
      ok = false;
  }
  Reply(q, ok ? q.flags : static_cast<uint8_t>(q.flags | kFlagNack), {});
}

std::vector<int> Dlpc350Emulator::LutPatterns() const {
  if (pattern_config.size() != 4 || image_lut.empty()) return {};
  std::vector<uint8_t> images = image_lut;
  if (images.size() >= 2) std::swap(images[0], images[1]);  // as the device reads them
  const size_t entries = std::min<size_t>(size_t(pattern_config[0]) + 1, pattern_lut.size() / 3);
  std::vector<int> patterns;
  size_t image_at = 0;
  for (size_t e = 0; e < entries; ++e) {
    const uint32_t w = uint32_t(pattern_lut[3 * e]) | uint32_t(pattern_lut[3 * e + 1]) << 8 |
                       uint32_t(pattern_lut[3 * e + 2]) << 16;
    const int number = (w >> 2) & 0x3F, depth = (w >> 8) & 0xF;
    if (e > 0 && (w >> 18 & 1)) ++image_at;
    if (depth < 1 || depth > 8 || image_at >= images.size()) return {};
    patterns.push_back(images[image_at] * (24 / depth) + number);
  }
  return patterns;
}

Dlpc350SequenceRunner::Dlpc350SequenceRunner() : thread_([this] { Loop(); }) {}

Dlpc350SequenceRunner::~Dlpc350SequenceRunner() {
  {
    std::lock_guard lock(mutex_);
    quit_ = true;
    ++generation_;
  }
  wake_.notify_all();
  thread_.join();
}

void Dlpc350SequenceRunner::Start(std::vector<int> patterns, uint32_t frame_period_us) {
  {
    std::lock_guard lock(mutex_);
    patterns_ = std::move(patterns);
    period_ = std::chrono::microseconds(frame_period_us);
    start_ = std::chrono::steady_clock::now();
    start_system_ = std::chrono::system_clock::now();
    running_ = true;
    ++generation_;
  }
  wake_.notify_all();
}

void Dlpc350SequenceRunner::Stop() {
  {
    std::lock_guard lock(mutex_);
    running_ = false;
    ++generation_;
  }
  wake_.notify_all();
}

void Dlpc350SequenceRunner::Loop() {
  std::unique_lock lock(mutex_);
  for (;;) {
    wake_.wait(lock, [&] { return quit_ || running_; });
    if (quit_) return;
    const uint64_t generation = generation_;
    const std::vector<int> patterns = patterns_;
    const auto period = period_;
    const auto start = start_;
    const auto start_system = start_system_;
    ++runs_;
    bool halted = false;
    for (size_t e = 0; e < patterns.size() && generation_ == generation; ++e) {
      const int entry = static_cast<int>(e);
      if (halt_at.load() == entry) {
        halt_at = -1;
        halted = true;
        break;
      }
      showing_ = patterns[e];
      const bool drop = drop_pulse_at.load() == entry;
      if (drop) drop_pulse_at = -1;
      if (!drop && trigger_out) {
        lock.unlock();
        trigger_out(entry, patterns[e],
                    start_system + std::chrono::duration_cast<std::chrono::system_clock::duration>(
                                       static_cast<int64_t>(e) * period));
        ++pulses_;
        lock.lock();
      }
      wake_.wait_until(lock, start + (e + 1) * period, [&] { return generation_ != generation; });
    }
    showing_ = -1;
    if (generation_ == generation) running_ = false;
    if (halted && on_halt) {
      lock.unlock();
      on_halt();
      lock.lock();
    }
  }
}

bool MemoryTransport::Write(const Report& report, std::chrono::milliseconds) {
  if (!accept_writes) return false;
  written.push_back(report);
  device_.Receive(report);
  return true;
}

bool MemoryTransport::Read(Report* report, std::chrono::milliseconds) {
  return device_.PopReply(report);
}

}  // namespace slshadow::capture::testing
