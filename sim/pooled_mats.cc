#include "sim/pooled_mats.h"

#include <algorithm>
#include <cstdlib>
#include <map>
#include <mutex>
#include <new>

namespace slshadow {
namespace {

// Large buffers (geometry buffers, rendered images) in page-aligned blocks rounded up to 2 MB
// size classes, recycled through a bounded process-wide pool: the geometry pass writes ~60 bytes
// per pixel into fresh buffers and the pattern pass ~2.3 MB per image, and the kernel's
// first-touch faults (page zeroing) cost about a fifth of a scan. Freed blocks are kept (up to
// kPoolCap bytes: a 2-camera 1920x1200 scan with 38 patterns recycles ~500 MB, exact size match)
// and handed to the next allocation of the same size, e.g. the next scan's buffers. Not zeroed:
// every user writes every element.
class BlockPool {
 public:
  static constexpr size_t kPage = 4096;
  static constexpr size_t kHuge = size_t{2}
                                  << 20;  // size classes (pages past the end are never touched)
  static constexpr size_t kPoolCap = size_t{640} << 20;
  static BlockPool& Get() {
    static BlockPool* pool = new BlockPool();  // never destroyed: buffers may outlive statics
    return *pool;
  }
  static size_t Rounded(size_t bytes) { return (bytes + kHuge - 1) / kHuge * kHuge; }
  // Frees every cached block (blocks in use are untouched and return to the pool when freed).
  void Release() {
    const std::lock_guard<std::mutex> lock(mutex_);
    for (const auto& [bytes, p] : free_) std::free(p);
    free_.clear();
    cached_ = 0;
  }
  void* Allocate(size_t bytes) {
    const size_t rounded = Rounded(std::max<size_t>(bytes, 1));
    {
      const std::lock_guard<std::mutex> lock(mutex_);
      const auto it = free_.find(rounded);
      if (it != free_.end()) {
        void* p = it->second;
        free_.erase(it);
        cached_ -= rounded;
        return p;
      }
    }
    // Page-aligned, 4 kB pages: advising transparent huge pages (MADV_HUGEPAGE) made the first
    // scan of a process ~1 CPU s slower on this machine (2 MB zeroing and compaction per fault:
    // 2.2-2.6 vs 1.3-1.4 CPU s for the demo scan, same run), and recycling removes the faults of
    // later scans anyway.
    void* p = std::aligned_alloc(kPage, rounded);
    if (!p) throw std::bad_alloc();
    return p;
  }
  void Free(void* p, size_t bytes) {
    if (!p) return;
    const size_t rounded = Rounded(std::max<size_t>(bytes, 1));
    {
      const std::lock_guard<std::mutex> lock(mutex_);
      if (cached_ + rounded <= kPoolCap) {
        free_.emplace(rounded, p);
        cached_ += rounded;
        return;
      }
    }
    std::free(p);
  }

 private:
  std::mutex mutex_;
  std::multimap<size_t, void*> free_;
  size_t cached_ = 0;
};

// cv::Mat storage from the BlockPool. Same bookkeeping as OpenCV's standard allocator.
class PooledMatAllocator : public cv::MatAllocator {
 public:
  cv::UMatData* allocate(int dims, const int* sizes, int type, void* data0, size_t* step,
                         cv::AccessFlag, cv::UMatUsageFlags) const override {
    size_t total = CV_ELEM_SIZE(type);
    for (int i = dims - 1; i >= 0; i--) {
      if (step) {
        if (data0 && step[i] != cv::Mat::AUTO_STEP) {
          total = step[i];
        } else {
          step[i] = total;
        }
      }
      total *= static_cast<size_t>(sizes[i]);
    }
    uchar* data = static_cast<uchar*>(data0);
    if (!data) data = static_cast<uchar*>(BlockPool::Get().Allocate(total));
    auto* u = new cv::UMatData(this);
    u->data = u->origdata = data;
    u->size = total;
    if (data0) u->flags |= cv::UMatData::USER_ALLOCATED;
    return u;
  }
  bool allocate(cv::UMatData* u, cv::AccessFlag, cv::UMatUsageFlags) const override {
    return u != nullptr;
  }
  void deallocate(cv::UMatData* u) const override {
    if (!u) return;
    if (!(u->flags & cv::UMatData::USER_ALLOCATED)) BlockPool::Get().Free(u->origdata, u->size);
    delete u;
  }
};

}  // namespace

cv::MatAllocator* PooledMats() {
  static PooledMatAllocator* allocator =
      new PooledMatAllocator();  // never destroyed: Mats may outlive statics
  return allocator;
}

void ReleaseSimulatorPool() { BlockPool::Get().Release(); }

void CreatePooled(cv::Mat& m, int rows, int cols, int type) {
  m.release();
  m.allocator = PooledMats();
  m.create(rows, cols, type);
}

}  // namespace slshadow
