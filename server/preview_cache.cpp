#include "preview_cache.h"

namespace lf::server {

namespace {

uint64_t size_of(const std::map<PreviewKind, Preview>& previews) {
    uint64_t bytes = 0;
    for (const auto& [kind, preview] : previews) {
        bytes += preview.png.size();
        for (const auto& [name, value] : preview.headers) bytes += name.size() + value.size();
    }
    return bytes;
}

}  // namespace

std::optional<std::map<PreviewKind, Preview>> PreviewCache::find(const std::string& id, const std::string& source) {
    std::lock_guard lock(mutex_);
    const auto it = entries_.find(id);
    if (it == entries_.end() || it->second.source != source) return std::nullopt;
    it->second.last_used = ++clock_;
    return it->second.previews;
}

void PreviewCache::keep(const std::string& id, const std::string& source,
                        const std::map<PreviewKind, Preview>& previews) {
    std::lock_guard lock(mutex_);
    if (const auto it = entries_.find(id); it != entries_.end()) drop(it);
    const uint64_t bytes = size_of(previews);
    if (bytes > budget_) return;
    entries_[id] = {source, previews, bytes, ++clock_};
    bytes_ += bytes;
    while (bytes_ > budget_) {
        auto oldest = entries_.begin();
        for (auto it = entries_.begin(); it != entries_.end(); ++it)
            if (it->second.last_used < oldest->second.last_used) oldest = it;
        drop(oldest);
    }
}

void PreviewCache::drop(std::map<std::string, Entry>::iterator it) {
    bytes_ -= it->second.bytes;
    entries_.erase(it);
}

uint64_t PreviewCache::bytes() const {
    std::lock_guard lock(mutex_);
    return bytes_;
}

size_t PreviewCache::jobs() const {
    std::lock_guard lock(mutex_);
    return entries_.size();
}

}  // namespace lf::server
