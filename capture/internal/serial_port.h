// A serial port through termios, line oriented: raw 8N1, no flow control, the given speed, reads
// with a deadline. Used by the GRBL turntable; a pseudo-terminal's slave works the same way.
// Errors throw TurntableError: kDisconnected when the port cannot be opened or vanishes (end of
// file, EIO, hang-up), kRefused for a path that is no terminal or a speed it cannot take; the
// messages name the port, the caller adds the device and the request.
#pragma once

#include <chrono>
#include <optional>
#include <string>

namespace slshadow::capture::internal {

class SerialPort {
 public:
  using Clock = std::chrono::steady_clock;
  // Opens `path` exclusively (TIOCEXCL), raw, at `baud` (9600 ... 1000000 bit/s).
  SerialPort(const std::string& path, int baud);
  ~SerialPort();
  SerialPort(const SerialPort&) = delete;
  SerialPort& operator=(const SerialPort&) = delete;

  // Writes all bytes (waits at most until `deadline` for room in the output queue).
  void Write(const std::string& bytes, Clock::time_point deadline);
  // The next line (CR / LF stripped, empty lines skipped), or nullopt at the deadline.
  std::optional<std::string> ReadLine(Clock::time_point deadline);
  // Drops the bytes received and not yet read.
  void DiscardInput();

 private:
  [[noreturn]] void Vanished(const std::string& what) const;
  int fd_ = -1;
  std::string path_;
  std::string buffer_;  // bytes read, not yet returned as lines
};

}  // namespace slshadow::capture::internal
