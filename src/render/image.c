/* 8-bit RGB images: allocation, PNG files through libpng (written atomically), area-averaged resizing and
 * labelled contact sheets. */
#include <errno.h>
#include <png.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "io/io.h"
#include "render/render.h"

#define IMAGE_MAX_SIDE 65535

DrStatus dr_image_create(int width, int height, const uint8_t fill[3], DrImage *out, DrError *err)
{
    assert(fill && out);
    *out = (DrImage){0};
    if (width < 1 || height < 1 || width > IMAGE_MAX_SIDE || height > IMAGE_MAX_SIDE)
        return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0,
                            "image size %dx%d is invalid: each side must be between 1 and %d pixels", width, height,
                            IMAGE_MAX_SIDE);
    size_t n = (size_t)width * (size_t)height;
    uint8_t *rgb = NULL;
    DR_TRY(dr_calloc(n, 3, &rgb, err));
    for (size_t i = 0; i < n; i++) memcpy(rgb + 3 * i, fill, 3);
    *out = (DrImage){width, height, rgb};
    return DR_OK;
}

void dr_image_free(DrImage *img)
{
    if (!img) return;
    free(img->rgb);
    *img = (DrImage){0};
}

/* ---- PNG ------------------------------------------------------------------------------------------- */

/* libpng reports errors by calling this and longjmp-ing back to the setjmp in the caller; the message is
 * kept so the DrError can quote it. */
typedef struct PngMessage {
    char text[256];
} PngMessage;

static void png_on_error(png_structp png, png_const_charp msg)
{
    PngMessage *m = png_get_error_ptr(png);
    if (m) snprintf(m->text, sizeof m->text, "%s", msg);
    png_longjmp(png, 1);
}

static void png_on_warning(png_structp png, png_const_charp msg)
{
    (void)png;
    (void)msg; /* warnings (e.g. a bad ancillary chunk) do not stop the read; stay quiet */
}

/* Writes img to an open stream; false with m->text filled on a libpng failure. Kept apart from the file
 * handling so that nothing but libpng state lives across the setjmp. */
static bool png_write_stream(FILE *f, const DrImage *img, PngMessage *m)
{
    png_structp png = png_create_write_struct(PNG_LIBPNG_VER_STRING, m, png_on_error, png_on_warning);
    if (!png) {
        snprintf(m->text, sizeof m->text, "libpng could not be initialised");
        return false;
    }
    png_infop info = png_create_info_struct(png);
    if (!info || setjmp(png_jmpbuf(png))) {
        if (!info) snprintf(m->text, sizeof m->text, "libpng could not be initialised");
        png_destroy_write_struct(&png, &info);
        return false;
    }
    png_init_io(png, f);
    /* level 6 is libpng's default trade-off; previews are written once and read by people */
    png_set_compression_level(png, 6);
    png_set_IHDR(png, info, (png_uint_32)img->width, (png_uint_32)img->height, 8, PNG_COLOR_TYPE_RGB,
                 PNG_INTERLACE_NONE, PNG_COMPRESSION_TYPE_DEFAULT, PNG_FILTER_TYPE_DEFAULT);
    png_set_sRGB(png, info, PNG_sRGB_INTENT_PERCEPTUAL);
    png_write_info(png, info);
    for (int y = 0; y < img->height; y++) png_write_row(png, img->rgb + 3 * (size_t)y * (size_t)img->width);
    png_write_end(png, info);
    png_destroy_write_struct(&png, &info);
    return true;
}

DrStatus dr_image_write_png(const char *path, const DrImage *img, DrError *err)
{
    assert(path && img && img->rgb && img->width >= 1 && img->height >= 1);
    char tmp[DR_IO_PATH_MAX];
    if (strlen(path) + 32 > sizeof tmp)
        return dr_error_set(err, DR_ERR_IO, path, 0, 0, "the path is too long (at most 4096 bytes)");
    dr_io_tmp_path(path, tmp, sizeof tmp);
    FILE *f = fopen(tmp, "wb");
    if (!f)
        return dr_error_set(err, DR_ERR_IO, path, 0, 0,
                            "cannot create %s: %s; check that the directory exists and is writable", tmp,
                            strerror(errno));
    PngMessage m = {""};
    bool ok = png_write_stream(f, img, &m);
    int flush_errno = 0;
    if (ok && (fflush(f) != 0 || ferror(f))) {
        flush_errno = errno;
        ok = false;
    }
    if (fclose(f) != 0 && ok) {
        flush_errno = errno;
        ok = false;
    }
    if (!ok) {
        unlink(tmp);
        if (m.text[0])
            return dr_error_set(err, DR_ERR_IO, path, 0, 0, "cannot write the PNG: %s", m.text);
        return dr_error_set(err, DR_ERR_IO, path, 0, 0, "cannot write the PNG: %s; check free disk space",
                            strerror(flush_errno ? flush_errno : EIO));
    }
    return dr_io_commit(tmp, path, err);
}

/* Decodes a PNG stream into *out (rgb allocated here); false with m->text filled when libpng fails or the
 * image is too large. */
static bool png_read_stream(FILE *f, DrImage *out, PngMessage *m)
{
    png_structp png = png_create_read_struct(PNG_LIBPNG_VER_STRING, m, png_on_error, png_on_warning);
    if (!png) {
        snprintf(m->text, sizeof m->text, "libpng could not be initialised");
        return false;
    }
    png_infop info = png_create_info_struct(png);
    /* written after setjmp, read after a longjmp: volatile so the value survives */
    uint8_t *volatile rgb = NULL;
    png_bytep *volatile rows = NULL;
    if (!info || setjmp(png_jmpbuf(png))) {
        if (!info) snprintf(m->text, sizeof m->text, "libpng could not be initialised");
        free(rgb);
        free(rows);
        png_destroy_read_struct(&png, &info, NULL);
        return false;
    }
    png_init_io(png, f);
    png_read_info(png, info);
    png_uint_32 w = png_get_image_width(png, info), h = png_get_image_height(png, info);
    if (w < 1 || h < 1 || w > IMAGE_MAX_SIDE || h > IMAGE_MAX_SIDE)
        png_error(png, "image size is outside 1..65535 pixels per side");
    /* every colour type to 8-bit RGB: palette and low-bit grey expanded, 16-bit stripped, alpha dropped */
    png_set_expand(png);
    png_set_strip_16(png);
    png_set_strip_alpha(png);
    png_set_gray_to_rgb(png);
    png_set_interlace_handling(png);
    png_read_update_info(png, info);
    if (png_get_rowbytes(png, info) != 3 * (size_t)w) png_error(png, "unexpected row layout after conversion");
    rgb = malloc(3 * (size_t)w * (size_t)h);
    rows = malloc(sizeof(png_bytep) * (size_t)h);
    if (!rgb || !rows) png_error(png, "out of memory");
    for (png_uint_32 y = 0; y < h; y++) rows[y] = rgb + 3 * (size_t)y * (size_t)w;
    png_read_image(png, rows);
    png_read_end(png, NULL);
    png_destroy_read_struct(&png, &info, NULL);
    free(rows);
    *out = (DrImage){(int)w, (int)h, rgb};
    return true;
}

DrStatus dr_image_read_png(const char *path, DrImage *out, DrError *err)
{
    assert(path && out);
    *out = (DrImage){0};
    FILE *f = fopen(path, "rb");
    if (!f)
        return dr_error_set(err, DR_ERR_INPUT, path, 0, 0, "cannot open the PNG: %s", strerror(errno));
    uint8_t sig[8];
    size_t got = fread(sig, 1, sizeof sig, f);
    if (got != sizeof sig || png_sig_cmp(sig, 0, sizeof sig) != 0) {
        fclose(f);
        return dr_error_set(err, DR_ERR_INPUT, path, 0, 0,
                            "not a PNG file (the PNG signature is missing); re-render or replace it");
    }
    rewind(f);
    PngMessage m = {""};
    bool ok = png_read_stream(f, out, &m);
    fclose(f);
    if (!ok)
        return dr_error_set(err, DR_ERR_INPUT, path, 0, 0, "the PNG is corrupt or truncated (libpng: %s); re-render it",
                            m.text);
    return DR_OK;
}

/* ---- resizing ---------------------------------------------------------------------------------------- */

/* Overlap weights of a 1-D area resampling from n source cells onto m destination cells: destination cell
 * d covers source interval [d*n/m, (d+1)*n/m); first[d] is its first source cell, and w[d*span + k] the
 * overlap with source cell first[d] + k (span = cells any destination may touch). */
static int resample_span(int n, int m) { return n / m + 2; }

static void resample_weights(int n, int m, int span, int *first, double *w)
{
    double scale = (double)n / (double)m;
    for (int d = 0; d < m; d++) {
        double a = d * scale, b = (d + 1) * scale;
        int s0 = (int)floor(a);
        first[d] = s0;
        for (int k = 0; k < span; k++) {
            int s = s0 + k;
            double lo = fmax(a, (double)s), hi = fmin(b, (double)s + 1.0);
            w[d * span + k] = (s < n && hi > lo) ? hi - lo : 0.0;
        }
    }
}

DrStatus dr_image_resize(const DrImage *src, int w, int h, DrImage *out, DrError *err)
{
    assert(src && src->rgb && out);
    static const uint8_t black[3] = {0, 0, 0};
    DR_TRY(dr_image_create(w, h, black, out, err));
    int sx = resample_span(src->width, w), sy = resample_span(src->height, h);
    int *fx = NULL, *fy = NULL;
    double *wx = NULL, *wy = NULL, *row = NULL;
    DrStatus s = dr_calloc((size_t)w, sizeof *fx, &fx, err);
    if (s == DR_OK) s = dr_calloc((size_t)h, sizeof *fy, &fy, err);
    if (s == DR_OK) s = dr_calloc((size_t)w * (size_t)sx, sizeof *wx, &wx, err);
    if (s == DR_OK) s = dr_calloc((size_t)h * (size_t)sy, sizeof *wy, &wy, err);
    /* one horizontally resampled source row per destination row tap, accumulated in place */
    if (s == DR_OK) s = dr_calloc(3 * (size_t)w, sizeof *row, &row, err);
    if (s == DR_OK) {
        resample_weights(src->width, w, sx, fx, wx);
        resample_weights(src->height, h, sy, fy, wy);
        for (int y = 0; y < h; y++) {
            memset(row, 0, 3 * (size_t)w * sizeof *row);
            double wsum_y = 0.0;
            for (int ky = 0; ky < sy; ky++) {
                double wyk = wy[y * sy + ky];
                if (wyk == 0.0) continue;
                wsum_y += wyk;
                const uint8_t *srow = src->rgb + 3 * (size_t)(fy[y] + ky) * (size_t)src->width;
                for (int x = 0; x < w; x++) {
                    double acc[3] = {0, 0, 0}, wsum_x = 0.0;
                    for (int kx = 0; kx < sx; kx++) {
                        double wxk = wx[x * sx + kx];
                        if (wxk == 0.0) continue;
                        wsum_x += wxk;
                        const uint8_t *p = srow + 3 * (size_t)(fx[x] + kx);
                        for (int c = 0; c < 3; c++) acc[c] += wxk * p[c];
                    }
                    for (int c = 0; c < 3; c++) row[3 * x + c] += wyk * acc[c] / wsum_x;
                }
            }
            /* dividing by the summed weights keeps a constant image exactly constant */
            for (int x = 0; x < 3 * w; x++) {
                double v = row[x] / wsum_y;
                out->rgb[3 * (size_t)y * (size_t)w + (size_t)x] = (uint8_t)fmin(255.0, fmax(0.0, floor(v + 0.5)));
            }
        }
    }
    free(fx);
    free(fy);
    free(wx);
    free(wy);
    free(row);
    if (s != DR_OK) dr_image_free(out);
    return s;
}

/* ---- contact sheets ------------------------------------------------------------------------------------ */

DrStatus dr_image_contact_sheet(const DrImage *images, const char *const *labels, int count, int columns,
                                int thumb_width, DrImage *out, DrError *err)
{
    assert(out);
    *out = (DrImage){0};
    if (count < 1 || !images)
        return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0, "a contact sheet needs at least one image");
    if (columns < 1)
        return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0, "contact sheet columns %d must be at least 1", columns);
    if (thumb_width < DR_SHEET_MIN_THUMB || thumb_width > IMAGE_MAX_SIDE)
        return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0,
                            "contact sheet thumb_width %d must be between %d and %d pixels", thumb_width,
                            DR_SHEET_MIN_THUMB, IMAGE_MAX_SIDE);
    for (int i = 1; i < count; i++)
        if (images[i].width != images[0].width || images[i].height != images[0].height)
            return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0,
                                "contact sheet images differ in size: image %d is %dx%d, image 0 is %dx%d", i,
                                images[i].width, images[i].height, images[0].width, images[0].height);
    DrSheetLayout L;
    dr_image_sheet_layout(images[0].width, images[0].height, count, columns, thumb_width, &L);
    static const uint8_t background[3] = {24, 24, 27}, ink[3] = {225, 225, 220};
    DR_TRY(dr_image_create(L.width, L.height, background, out, err));
    for (int i = 0; i < count; i++) {
        int x0 = DR_SHEET_MARGIN + (i % L.columns) * (L.thumb_width + DR_SHEET_MARGIN);
        int y0 = DR_SHEET_MARGIN + (i / L.columns) * (L.thumb_height + L.label_height + DR_SHEET_MARGIN);
        DrImage t;
        DrStatus s = dr_image_resize(&images[i], L.thumb_width, L.thumb_height, &t, err);
        if (s != DR_OK) {
            dr_image_free(out);
            return s;
        }
        for (int y = 0; y < t.height; y++)
            memcpy(out->rgb + 3 * ((size_t)(y0 + y) * (size_t)L.width + (size_t)x0),
                   t.rgb + 3 * (size_t)y * (size_t)t.width, 3 * (size_t)t.width);
        dr_image_free(&t);
        if (!labels || !labels[i]) continue;
        /* as many characters as fit under the thumbnail, so a long label never runs into its neighbour */
        char text[256];
        snprintf(text, sizeof text, "%s", labels[i]);
        int tw, th;
        dr_image_text_size(text, L.label_scale, &tw, &th);
        while (tw > L.thumb_width) {
            text[strlen(text) - 1] = '\0';
            dr_image_text_size(text, L.label_scale, &tw, &th);
        }
        dr_image_draw_text(out, x0, y0 + L.thumb_height + DR_SHEET_LABEL_PAD, L.label_scale, ink, text);
    }
    return DR_OK;
}

void dr_image_sheet_layout(int image_width, int image_height, int count, int columns, int thumb_width,
                           DrSheetLayout *layout)
{
    assert(image_width >= 1 && image_height >= 1 && count >= 1 && columns >= 1 && thumb_width >= 1);
    DrSheetLayout L;
    L.columns = columns < count ? columns : count;
    L.rows = (count + L.columns - 1) / L.columns;
    L.thumb_width = thumb_width;
    L.thumb_height = (int)floor((double)thumb_width * image_height / image_width + 0.5);
    if (L.thumb_height < 1) L.thumb_height = 1;
    L.label_scale = thumb_width >= 200 ? 2 : 1;
    L.label_height = 7 * L.label_scale + 2 * DR_SHEET_LABEL_PAD;
    L.width = DR_SHEET_MARGIN + L.columns * (L.thumb_width + DR_SHEET_MARGIN);
    L.height = DR_SHEET_MARGIN + L.rows * (L.thumb_height + L.label_height + DR_SHEET_MARGIN);
    *layout = L;
}
