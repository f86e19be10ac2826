/*
 * A use-after-free detector for one class of heap blocks, preloaded into a host process
 * (LD_PRELOAD) by tests/test_exit.py.
 *
 * pythonfmu's exit crash (test_exit.py's docstring) is a write into a freed 128-byte block (the
 * std::shared_ptr's control block) between exit()'s static destructors and the library
 * finalizers.  glibc notices it only when that block happens to sit in a bin whose pointers the
 * write corrupts (3 to 37 runs in 100), so a test that waits for the abort needs many runs.  This
 * library makes it certain: free() of a block of about that size does not return it to glibc but
 * fills it with a pattern and keeps it in a ring; a block leaving the ring, and every block still
 * in it when the process ends, must still hold the pattern (0x11 bytes: a reference count read there is positive, so a release
 * writes it rather than jumping through a null vtable).  A changed byte is reported on stderr and the process ends with status
 * QUARANTINE_STATUS (86).
 *
 *   cc -std=c11 -O1 -fPIC -shared -o quarantine_free.so quarantine_free.c -lpthread
 */
#define _GNU_SOURCE
#include <malloc.h>
#include <pthread.h>
#include <stddef.h>
#include <stdio.h>
#include <string.h>
#include <unistd.h>

#define QUARANTINE_STATUS 86
#define RING 65536
#define PATTERN 0x11
#define SMALLEST 104          /* usable sizes kept: a 128-byte request has 136 usable bytes in glibc */
#define LARGEST 152

extern void __libc_free(void* p);

static struct { unsigned char* p; size_t n; } ring[RING];
static size_t next_slot, kept;
static pthread_mutex_t lock = PTHREAD_MUTEX_INITIALIZER;

static void report(const unsigned char* p, size_t n, size_t at)
{
    char text[200];
    int len = snprintf(text, sizeof text,
                       "quarantine_free: a freed %zu-byte block at %p was written after free() (byte %zu is "
                       "0x%02x, not 0x%02x)\n", n, (const void*)p, at, p[at], PATTERN);
    if (len > 0) (void)!write(2, text, (size_t)len);
    _exit(QUARANTINE_STATUS);
}

static void check(const unsigned char* p, size_t n)
{
    for (size_t k = 0; k < n; ++k)
        if (p[k] != PATTERN) report(p, n, k);
}

void free(void* ptr)
{
    if (!ptr) return;
    size_t n = malloc_usable_size(ptr);
    if (n < SMALLEST || n > LARGEST) {
        __libc_free(ptr);
        return;
    }
    memset(ptr, PATTERN, n);
    pthread_mutex_lock(&lock);
    unsigned char* old = ring[next_slot].p;
    size_t old_n = ring[next_slot].n;
    ring[next_slot].p = ptr;
    ring[next_slot].n = n;
    next_slot = (next_slot + 1) % RING;
    if (kept < RING) ++kept;
    if (old) check(old, old_n);
    pthread_mutex_unlock(&lock);
    if (old) __libc_free(old);
}

/* The last check runs when the C library flushes its streams at exit (after the atexit handlers,
 * the static destructors and every library's finalizer; a destructor function here ran before the
 * wrapper's in a test): a stream of this library holds one unwritten byte, and its write function is
 * the check.  It says so on stderr ("... intact (at exit)"): a program's fflush(NULL) would run it
 * early and leave nothing to flush at exit, and the tests look for that line. */
static ssize_t check_all(void* cookie, const char* buffer, size_t size)
{
    (void)cookie;
    (void)buffer;
    pthread_mutex_lock(&lock);
    for (size_t k = 0; k < RING; ++k)
        if (ring[k].p) check(ring[k].p, ring[k].n);
    char text[120];
    int len = snprintf(text, sizeof text, "quarantine_free: %zu freed blocks intact (at exit)\n", kept);
    if (len > 0) (void)!write(2, text, (size_t)len);
    pthread_mutex_unlock(&lock);
    return (ssize_t)size;
}

__attribute__((constructor)) static void arm(void)
{
    static char buffer[16];
    FILE* at_exit = fopencookie(NULL, "w", (cookie_io_functions_t){.write = check_all});
    if (!at_exit || setvbuf(at_exit, buffer, _IOFBF, sizeof buffer) || fputc('.', at_exit) == EOF) {
        static const char text[] = "quarantine_free: cannot arm the check at exit\n";
        (void)!write(2, text, sizeof text - 1);
        _exit(QUARANTINE_STATUS + 1);
    }
}
