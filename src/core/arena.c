/* Bump allocator for per-step scratch. */
#include "core.h"

#include <stdlib.h>
#include <string.h>

typedef struct Block {
    struct Block *next;
    size_t size, used;
    unsigned char *data;
} Block;

struct DrArena {
    Block *head; /* current block first */
    size_t block_bytes;
};

DrStatus dr_arena_create(size_t block_bytes, DrArena **out, DrError *err)
{
    DR_TRY(dr_calloc(1, sizeof(DrArena), out, err));
    (*out)->block_bytes = block_bytes < 4096 ? 4096 : block_bytes;
    return DR_OK;
}

void dr_arena_destroy(DrArena **arena)
{
    if (!arena || !*arena) return;
    Block *b = (*arena)->head;
    while (b) {
        Block *n = b->next;
        free(b->data);
        free(b);
        b = n;
    }
    free(*arena);
    *arena = NULL;
}

void *dr_arena_alloc(DrArena *a, size_t count, size_t size)
{
    size_t bytes;
    if (dr_mul_overflows(count, size, &bytes) || bytes > SIZE_MAX - 64) return NULL;
    bytes = (bytes + 63) & ~(size_t)63;
    if (bytes == 0) bytes = 64;
    Block *b = a->head;
    if (!b || b->used + bytes > b->size) {
        /* look for a free block further down (after a reset all blocks are empty) */
        Block *prev = NULL, *it = a->head;
        while (it && it->used + bytes > it->size) { prev = it; it = it->next; }
        if (it) {
            if (prev) { prev->next = it->next; it->next = a->head; a->head = it; }
            b = it;
        } else {
            size_t sz = bytes > a->block_bytes ? bytes : a->block_bytes;
            dr_alloc_count_add_();
            b = calloc(1, sizeof *b);
            if (!b) return NULL;
            b->data = aligned_alloc(64, sz);
            if (!b->data) { free(b); return NULL; }
            b->size = sz;
            b->next = a->head;
            a->head = b;
        }
    }
    void *p = b->data + b->used;
    b->used += bytes;
    memset(p, 0, bytes);
    return p;
}

void dr_arena_reset(DrArena *a)
{
    for (Block *b = a->head; b; b = b->next) b->used = 0;
}

size_t dr_arena_used(const DrArena *a)
{
    size_t u = 0;
    for (Block *b = a->head; b; b = b->next) u += b->used;
    return u;
}
