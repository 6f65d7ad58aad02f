/* Content hashing: XXH3-128 (libxxhash), used for cache keys and asset fingerprints. */
#include "core.h"

#include <errno.h>
#include <string.h>
#include <xxhash.h>

static DrHash from_xxh(XXH128_hash_t h)
{
    DrHash r = {h.high64, h.low64};
    return r;
}

DrHash dr_hash_bytes(const void *data, size_t size) { return from_xxh(XXH3_128bits(data, size)); }

void dr_hasher_init(DrHasher *h)
{
    XXH3_state_t *s = XXH3_createState();
    assert(s && "XXH3_createState");
    XXH3_128bits_reset(s);
    h->state = s;
}

void dr_hasher_update(DrHasher *h, const void *data, size_t size) { XXH3_128bits_update(h->state, data, size); }

void dr_hasher_update_str(DrHasher *h, const char *s) { dr_hasher_update(h, s, strlen(s) + 1); }

DrHash dr_hasher_final(DrHasher *h)
{
    DrHash r = from_xxh(XXH3_128bits_digest(h->state));
    XXH3_freeState(h->state);
    h->state = NULL;
    return r;
}

DrStatus dr_hash_file(const char *path, DrHash *out, DrError *err)
{
    FILE *f = fopen(path, "rb");
    if (!f)
        return dr_error_set(err, DR_ERR_INPUT, path, 0, 0, "cannot read file (%s); check the path", strerror(errno));
    DrHasher h;
    dr_hasher_init(&h);
    unsigned char buf[1 << 16];
    size_t n;
    while ((n = fread(buf, 1, sizeof buf, f)) > 0) dr_hasher_update(&h, buf, n);
    bool bad = ferror(f);
    fclose(f);
    *out = dr_hasher_final(&h);
    if (bad) return dr_error_set(err, DR_ERR_INPUT, path, 0, 0, "read error while hashing the file");
    return DR_OK;
}

void dr_hash_hex(DrHash h, char out[33]) { snprintf(out, 33, "%016llx%016llx", (unsigned long long)h.hi, (unsigned long long)h.lo); }
