// The write fault injector of the fault harness (issue #33), loaded with
// LD_PRELOAD into lightfarmd and lightfarm. It sees every data write those
// processes make to a file, whoever makes it: our code through C++ streams
// (libstdc++ calls write/writev), OpenEXR (C++ streams), tinygltf (a string
// we write), and SQLite's unix VFS (pwrite64, fsync/fdatasync, which it
// takes from libc by symbol). glibc's own stdio (fwrite, fflush, fclose)
// calls an internal write no shim can replace; nothing of ours writes a file
// through stdio, and the harness checks that: every file a dry run leaves
// behind must have been seen written here.
//
// The replaced calls have C linkage, and the shim calls no C++ library: it
// runs inside other processes' writes, on any of their threads.
//
// A write "site" is the process's name and the file's path below
// LF_FAULT_ROOT with its variable parts (ids, hashes, pids, pass numbers:
// any word with a digit in it, or 8 hex digits or more) written as '#', e.g.
// "lightfarmd jobs/#/lightmap.pass-#.exr".
//
//   LF_FAULT_ROOT   only regular files below this directory count
//   LF_FAULT_PROCS  the processes that count, by name (default "lightfarmd lightfarm")
//   LF_FAULT_LOG    every counted write appends "SITE\n" here (a dry run)
//   LF_FAULT_SITE   the site to fail
//   LF_FAULT_ERRNO  ENOSPC or EIO
//   LF_FAULT_ARMED  a file: while it is empty, the site's next write fails
//                   (in any process), and the shim appends a byte to it. The
//                   harness arms a fault where its scenario wants one by
//                   emptying the file, and sees whether it was taken.
#include <dlfcn.h>
#include <errno.h>
#include <fcntl.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <sys/uio.h>
#include <unistd.h>

namespace {

int hexdigit(char c) { return (c >= '0' && c <= '9') || (c >= 'a' && c <= 'f'); }
int alnum(char c) { return (c >= '0' && c <= '9') || (c >= 'a' && c <= 'z') || (c >= 'A' && c <= 'Z'); }

// "jobs/4f2a…/lightmap.pass-0004.exr" -> "jobs/#/lightmap.pass-#.exr"
void normalise(const char* path, char* out, size_t size) {
    size_t o = 0;
    for (size_t i = 0; path[i] && o + 2 < size;) {
        if (!alnum(path[i])) {
            out[o++] = path[i++];
            continue;
        }
        size_t j = i, digits = 0, hex = 1;
        for (; alnum(path[j]); ++j) {
            digits += path[j] >= '0' && path[j] <= '9';
            hex &= hexdigit(path[j]);
        }
        if (digits > 0 || (hex && j - i >= 8)) {
            out[o++] = '#';
        } else {
            for (; i < j && o + 2 < size; ++i) out[o++] = path[i];
        }
        i = j;
    }
    out[o] = 0;
}

int counted_process(void) {
    const char* procs = getenv("LF_FAULT_PROCS");
    if (!procs) procs = "lightfarmd lightfarm";
    const size_t n = strlen(program_invocation_short_name);
    for (const char* p = procs; (p = strstr(p, program_invocation_short_name)); p += n)
        if ((p == procs || p[-1] == ' ') && (p[n] == 0 || p[n] == ' ')) return 1;
    return 0;
}

// The site of a write to fd, or 0 when it is not one that counts (a pipe, a
// socket, a file outside the root, another process).
int site_of(int fd, char* site, size_t size) {
    const char* root = getenv("LF_FAULT_ROOT");
    struct stat st;
    if (!root || fstat(fd, &st) != 0 || !S_ISREG(st.st_mode) || !counted_process()) return 0;
    char link[64], path[4096];
    snprintf(link, sizeof link, "/proc/self/fd/%d", fd);
    const ssize_t n = readlink(link, path, sizeof path - 1);
    const size_t root_len = strlen(root);
    if (n <= 0) return 0;
    path[n] = 0;
    if (strncmp(path, root, root_len) != 0 || path[root_len] != '/') return 0;
    char rel[4096];
    normalise(path + root_len + 1, rel, sizeof rel);
    snprintf(site, size, "%s %s", program_invocation_short_name, rel);
    return 1;
}

ssize_t (*real_write)(int, const void*, size_t);

void append(const char* file, const char* text, size_t n) {
    if (!real_write) real_write = reinterpret_cast<decltype(real_write)>(dlsym(RTLD_NEXT, "write"));
    const int fd = open(file, O_WRONLY | O_APPEND | O_CREAT | O_CLOEXEC, 0600);
    if (fd < 0) return;
    (void)!real_write(fd, text, n);
    close(fd);
}

// Whether this write fails: logs its site (a dry run), and fails it when it
// is the wanted site's and the armed file is empty. errno is kept for a
// write that goes on.
int inject(int fd) {
    const int saved = errno;
    char site[4200];
    if (!site_of(fd, site, sizeof site)) return (errno = saved, 0);
    const char* log = getenv("LF_FAULT_LOG");
    const char* want = getenv("LF_FAULT_SITE");
    const char* armed = getenv("LF_FAULT_ARMED");
    if (log) {
        strcat(site, "\n");
        append(log, site, strlen(site));
        site[strlen(site) - 1] = 0;
    }
    struct stat st;
    if (!want || !armed || strcmp(site, want) != 0 || stat(armed, &st) != 0) return (errno = saved, 0);
    if (st.st_size > 0) return (errno = saved, 0);
    append(armed, "x", 1);
    const char* code = getenv("LF_FAULT_ERRNO");
    errno = code && strcmp(code, "EIO") == 0 ? EIO : ENOSPC;
    return 1;
}

}  // namespace

#define NEXT(name) (reinterpret_cast<decltype(&name)>(dlsym(RTLD_NEXT, #name)))

extern "C" {

ssize_t write(int fd, const void* buf, size_t n) {
    if (inject(fd)) return -1;
    if (!real_write) real_write = NEXT(write);
    return real_write(fd, buf, n);
}

ssize_t writev(int fd, const struct iovec* iov, int count) {
    if (inject(fd)) return -1;
    return NEXT(writev)(fd, iov, count);
}

ssize_t pwrite(int fd, const void* buf, size_t n, off_t at) {
    if (inject(fd)) return -1;
    return NEXT(pwrite)(fd, buf, n, at);
}

ssize_t pwrite64(int fd, const void* buf, size_t n, off64_t at) {
    if (inject(fd)) return -1;
    return NEXT(pwrite64)(fd, buf, n, at);
}

ssize_t pwritev(int fd, const struct iovec* iov, int count, off_t at) {
    if (inject(fd)) return -1;
    return NEXT(pwritev)(fd, iov, count, at);
}

int fsync(int fd) {
    if (inject(fd)) return -1;
    return NEXT(fsync)(fd);
}

int fdatasync(int fd) {
    if (inject(fd)) return -1;
    return NEXT(fdatasync)(fd);
}

}  // extern "C"
