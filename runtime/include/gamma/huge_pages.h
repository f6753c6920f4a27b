// An allocator for large arrays read at random by the tracer (the triangle
// lookup): a block of 2 MiB or more is placed on 2 MiB boundaries and
// advised as transparent huge pages (madvise MADV_HUGEPAGE) before it is
// first touched, so a random read costs fewer TLB misses (a 4 KiB page per
// read otherwise: the lookup of the bunny at 100k surfels spans ~10,000 of
// them).  Smaller blocks come from operator new.  Where transparent huge
// pages are off or unsupported the advice is ignored: same contents, 4 KiB
// pages.  Elements are constructed as std::allocator constructs them (a
// resize value-initialises): leaving them unwritten, as this allocator once
// did, saved no measurable set-up time (bench/RESULTS.md, 2026-12-04).
#pragma once
#include <cstddef>
#include <cstdlib>
#include <new>

#if defined(__linux__)
#include <sys/mman.h>
#endif

namespace gammart {

inline constexpr size_t kHugePageBytes = size_t(2) << 20;

template <class T>
struct HugePageAllocator {
    using value_type = T;
    HugePageAllocator() = default;
    template <class U>
    HugePageAllocator(const HugePageAllocator<U>&) noexcept {}

    T* allocate(size_t n) {
        if (n > size_t(-1) / sizeof(T)) throw std::bad_alloc();
        const size_t bytes = n * sizeof(T);
        if (bytes < kHugePageBytes) return static_cast<T*>(::operator new(bytes, std::align_val_t(alignof(T))));
        const size_t len = (bytes + kHugePageBytes - 1) / kHugePageBytes * kHugePageBytes;
        void* p = nullptr;
        if (posix_memalign(&p, kHugePageBytes, len) != 0 || p == nullptr) throw std::bad_alloc();
#if defined(__linux__) && defined(MADV_HUGEPAGE)
        madvise(p, len, MADV_HUGEPAGE);  // a hint: failure leaves 4 KiB pages
#endif
        return static_cast<T*>(p);
    }
    void deallocate(T* p, size_t n) noexcept {
        if (n * sizeof(T) < kHugePageBytes) ::operator delete(p, std::align_val_t(alignof(T)));
        else std::free(p);
    }
};

template <class T, class U>
bool operator==(const HugePageAllocator<T>&, const HugePageAllocator<U>&) noexcept {
    return true;
}
template <class T, class U>
bool operator!=(const HugePageAllocator<T>&, const HugePageAllocator<U>&) noexcept {
    return false;
}

}  // namespace gammart
