/* pngstat FILE.png X0 Y0 X1 Y1 [MIN]: pixel statistics of the rectangle [X0, X1) × [Y0, Y1) of a PNG (clipped to
 * the image), for the image checks of the pipeline tests. Prints one line
 *   mean R G B colours N
 * with the mean 8-bit sRGB value per channel and N the number of distinct colours other than pure white that
 * cover at least MIN pixels of the rectangle (default 1): with MIN above an antialiased edge's few pixels, N counts
 * the flat areas (a plot key's colour boxes). Exit 0, or 2 on bad arguments or an unreadable PNG. */
#include <stdlib.h>
#include <string.h>

#include "render/render.h"

static int cmp_u32(const void *a, const void *b)
{
    uint32_t x = *(const uint32_t *)a, y = *(const uint32_t *)b;
    return x < y ? -1 : x > y;
}

int main(int argc, char **argv)
{
    if (argc != 6 && argc != 7) {
        fprintf(stderr, "usage: pngstat FILE.png X0 Y0 X1 Y1 [MIN]\n");
        return 2;
    }
    DrImage img = {0};
    DrError err;
    if (dr_image_read_png(argv[1], &img, &err) < 0) {
        dr_error_print("pngstat", &err);
        return 2;
    }
    int x0 = atoi(argv[2]), y0 = atoi(argv[3]), x1 = atoi(argv[4]), y1 = atoi(argv[5]);
    long min = argc == 7 ? atol(argv[6]) : 1;
    x0 = x0 < 0 ? 0 : x0, y0 = y0 < 0 ? 0 : y0;
    x1 = x1 > img.width ? img.width : x1, y1 = y1 > img.height ? img.height : y1;
    if (x0 >= x1 || y0 >= y1) {
        fprintf(stderr, "pngstat: the rectangle lies outside the %dx%d image\n", img.width, img.height);
        return 2;
    }
    size_t n = (size_t)(x1 - x0) * (size_t)(y1 - y0), k = 0;
    uint32_t *c = malloc(n * sizeof *c);
    double sum[3] = {0, 0, 0};
    if (!c) return 2;
    for (int y = y0; y < y1; y++)
        for (int x = x0; x < x1; x++) {
            const uint8_t *p = img.rgb + 3 * ((size_t)y * img.width + x);
            for (int q = 0; q < 3; q++) sum[q] += p[q];
            c[k++] = (uint32_t)p[0] << 16 | (uint32_t)p[1] << 8 | p[2];
        }
    qsort(c, n, sizeof *c, cmp_u32);
    long colours = 0;
    for (size_t i = 0; i < n;) {
        size_t j = i;
        while (j < n && c[j] == c[i]) j++;
        if (c[i] != 0xffffffu && (long)(j - i) >= min) colours++;
        i = j;
    }
    printf("mean %.3f %.3f %.3f colours %ld\n", sum[0] / n, sum[1] / n, sum[2] / n, colours);
    free(c);
    dr_image_free(&img);
    return 0;
}
