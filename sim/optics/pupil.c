#include "sim/optics/pupil.h"

#include "sim/optics/bandpass.h"

#include "hal/arena.h"

#include <errno.h>
#include <fitsio.h>
#include <libdeflate.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <strings.h>
#include <sys/stat.h>

#define PI 3.14159265358979323846

wf_status wf_pupil_group_of_filter(const char *filter, wf_pupil_group *out)
{
    if (!filter) return wf_error(WF_ERR_INPUT, "pupil: no filter name");
    wf_filter f;
    wf_status st = wf_filter_parse(filter, &f); /* the one reading of filter names (W149 is W146) */
    if (st) {
        char msg[256];
        snprintf(msg, sizeof msg, "%s", wf_error_message());
        return wf_error(st, "pupil: %s", msg);
    }
    *out = f == WF_F184 || f == WF_K213 ? WF_PUPIL_LONG : WF_PUPIL_SHORT;
    return WF_OK;
}

wf_status wf_pupil_geometry_default(wf_pupil_group group, wf_pupil_geometry *out)
{
    if (group != WF_PUPIL_SHORT && group != WF_PUPIL_LONG)
        return wf_error(WF_ERR_RANGE, "pupil: group %d is neither short (0) nor long (1)", group);
    memset(out, 0, sizeof *out);
    out->diam = WF_PUPIL_DIAM;
    out->obscuration = WF_PUPIL_OBSCURATION;
    /* Six struts as measured on the SCA 1 short-wave mask and made exactly 3-fold symmetric:
     * not radial but offset 0.20 m from the axis, in two families 120° apart, 75.5 mm wide
     * (docs/OPTICS.md has the measurement). Radial struts would put the diffraction spikes at
     * the wrong angles. The long-wave group uses the same geometry: its mask differs mainly
     * in the larger cold-stop obscuration, which SPEC §2 leaves at 0.32 for the analytic model. */
    static const double family_deg[2] = {16.4, 42.4};
    static const double family_offset[2] = {-0.20, 0.20};
    out->nstruts = 6;
    for (int k = 0; k < 3; k++)
        for (int f = 0; f < 2; f++) {
            wf_pupil_strut *s = &out->strut[2 * k + f];
            s->angle_deg = family_deg[f] + 120.0 * k;
            s->offset_m = family_offset[f];
            s->width_m = 0.0755;
        }
    return WF_OK;
}

void wf_pupil_free(wf_pupil *p)
{
    if (!p) return;
    free(p->amp);
    p->amp = NULL;
}

static wf_status check_bin(int bin, int n, const char *what)
{
    if (bin != 1 && bin != 2 && bin != 4 && bin != 8)
        return wf_error(WF_ERR_RANGE, "%s: pupil_bin %d is not one of 1, 2, 4, 8", what, bin);
    if (n % bin || (n / bin) % 2)
        return wf_error(WF_ERR_INPUT, "%s: %d samples per side do not bin by %d to an even size",
                        what, n, bin);
    return WF_OK;
}

/* Bounding box and open area, which bound the FFT and the Fourier sums that follow. */
static void finish_pupil(wf_pupil *p)
{
    int n = p->n;
    p->i0 = n, p->i1 = -1, p->j0 = n, p->j1 = -1;
    double area = 0.0;
    for (int j = 0; j < n; j++)
        for (int i = 0; i < n; i++) {
            float a = p->amp[(size_t)j * n + i];
            if (a <= 0.0f) continue;
            area += (double)a * a;
            if (i < p->i0) p->i0 = i;
            if (i > p->i1) p->i1 = i;
            if (j < p->j0) p->j0 = j;
            if (j > p->j1) p->j1 = j;
        }
    p->open_area = area * p->dx * p->dx;
}

/* Path of a data file: <dir>/roman/<name> (dir laid out as ../shared/data) or <dir>/<name>
 * (dir is the roman folder itself). */
static wf_status data_path(const char *dir, const char *name, char *path, size_t size)
{
    struct stat st;
    const char *fmt[2] = {"%s/roman/%s", "%s/%s"};
    for (int k = 0; k < 2; k++) {
        int w = snprintf(path, size, fmt[k], dir, name);
        if (w < 0 || (size_t)w >= size)
            return wf_error(WF_ERR_INPUT, "data directory path '%s' is too long", dir);
        if (stat(path, &st) == 0 && S_ISREG(st.st_mode)) return WF_OK;
    }
    return wf_error(WF_ERR_IO, "%s: not found in %s/roman or %s", name, dir, dir);
}

static wf_status fits_fail(int status, const char *path, const char *doing)
{
    char text[FLEN_STATUS] = "";
    fits_get_errstatus(status, text);
    fits_clear_errmsg();
    return wf_error(WF_ERR_IO, "%s: %s: cfitsio error %d, %s", path, doing, status, text);
}

/* A gzip file read whole and inflated by libdeflate into a buffer of the size its trailer
 * gives, opened from memory: cfitsio would inflate it with zlib into a buffer it grows as it
 * goes, ~2.5x slower for the 8 MB masks (serial, before the PSF can start). NULL *mem, and
 * no error, when that does not apply (not gzip, several members, a size beyond the masks'
 * bound, any failure to inflate): the caller then opens the file through cfitsio, whose
 * messages name what is wrong with it. */
static void inflate_gz(const char *path, void **mem, size_t *size)
{
    *mem = NULL;
    *size = 0;
    FILE *fp = fopen(path, "rb");
    if (!fp) return;
    unsigned char *in = NULL, *out = NULL;
    long len = -1;
    if (fseek(fp, 0, SEEK_END) == 0) len = ftell(fp);
    if (len >= 18 && len < (1L << 30) && fseek(fp, 0, SEEK_SET) == 0 && (in = malloc((size_t)len)) &&
        fread(in, 1, (size_t)len, fp) == (size_t)len && in[0] == 0x1f && in[1] == 0x8b) {
        size_t isize = (size_t)in[len - 4] | (size_t)in[len - 3] << 8 | (size_t)in[len - 2] << 16 |
                       (size_t)in[len - 1] << 24;
        struct libdeflate_decompressor *d = NULL;
        size_t used = 0, got = 0;
        /* the largest mask wf_pupil_load takes: 16384^2 samples of 8 bytes, and its header */
        if (isize > 0 && isize <= ((size_t)1 << 31) + (1u << 20) && (out = wf_arena_host_realloc(NULL, 0, isize)) &&
            (d = libdeflate_alloc_decompressor()) &&
            libdeflate_gzip_decompress_ex(d, in, (size_t)len, out, isize, &used, &got) == LIBDEFLATE_SUCCESS &&
            used == (size_t)len && got == isize) {
            *mem = out;
            *size = isize;
            out = NULL;
        }
        if (d) libdeflate_free_decompressor(d);
    }
    free(out);
    free(in);
    fclose(fp);
}

wf_status wf_pupil_load(const char *data_dir, int sca, wf_pupil_group group, int bin,
                        wf_pupil_binning binning, wf_pupil *out)
{
    memset(out, 0, sizeof *out);
    if (!data_dir || !*data_dir) return wf_error(WF_ERR_INPUT, "pupil: no data directory given");
    if (sca < 1 || sca > 18) return wf_error(WF_ERR_RANGE, "pupil: SCA %d is not 1..18", sca);
    if (group != WF_PUPIL_SHORT && group != WF_PUPIL_LONG)
        return wf_error(WF_ERR_RANGE, "pupil: group %d is neither short nor long", group);
    char name[64], path[1024];
    snprintf(name, sizeof name, "RST_WIM_Filter_%s_SCA_%d.fits.gz",
             group == WF_PUPIL_LONG ? "F184" : "skinny", sca);
    wf_status st = data_path(data_dir, name, path, sizeof path);
    if (st) return st;

    fitsfile *f = NULL;
    int status = 0;
    void *mem;
    size_t memsize;
    inflate_gz(path, &mem, &memsize);
    /* else diskfile: the name is taken literally (no cfitsio [ext] syntax from a user's
     * folder); cfitsio uncompresses a .gz in memory itself */
    if (mem ? fits_open_memfile(&f, path, READONLY, &mem, &memsize, 0, NULL, &status)
            : fits_open_diskfile(&f, path, READONLY, &status)) {
        free(mem);
        return fits_fail(status, path, "opening the pupil mask");
    }
    int naxis = 0, bitpix = 0;
    long naxes[2] = {0, 0};
    if (fits_get_img_param(f, 2, &bitpix, &naxis, naxes, &status)) {
        st = fits_fail(status, path, "reading the image size");
        goto done;
    }
    if (naxis != 2 || naxes[0] != naxes[1] || naxes[0] < 2 || naxes[0] > 16384) {
        st = wf_error(WF_ERR_INPUT, "%s: pupil mask is %dD %ldx%ld, want a square 2D image", path,
                      naxis, naxes[0], naxes[1]);
        goto done;
    }
    int n0 = (int)naxes[0];
    if ((st = check_bin(bin, n0, path))) goto done;
    double scale = 0.0;
    if (fits_read_key_dbl(f, "PIXELSCL", &scale, NULL, &status) || !(scale > 0.0) ||
        !isfinite(scale)) {
        st = status ? fits_fail(status, path, "reading PIXELSCL (m per pupil sample)")
                    : wf_error(WF_ERR_INPUT, "%s: PIXELSCL = %g is not a positive scale", path,
                               scale);
        goto done;
    }
    int nb = n0 / bin;
    out->amp = malloc((size_t)nb * nb * sizeof(float));
    int *rows = malloc((size_t)n0 * bin * sizeof(int));
    if (!out->amp || !rows) {
        free(rows);
        st = wf_error(WF_ERR_NOMEM, "%s: cannot allocate the %dx%d pupil", path, nb, nb);
        goto done;
    }
    for (int J = 0; J < nb && !st; J++) {
        long fpixel[2] = {1, (long)J * bin + 1};
        int anynul = 0;
        if (fits_read_pix(f, TINT, fpixel, (LONGLONG)n0 * bin, NULL, rows, &anynul, &status)) {
            st = fits_fail(status, path, "reading pupil rows");
            break;
        }
        for (int I = 0; I < nb; I++) {
            int open = 0;
            for (int t = 0; t < bin; t++)
                for (int s = 0; s < bin; s++) open += rows[(size_t)t * n0 + (size_t)I * bin + s] != 0;
            float a = binning == WF_PUPIL_BIN_MEAN ? (float)open / (float)(bin * bin)
                                                   : (float)(open > 0);
            out->amp[(size_t)J * nb + I] = a;
        }
    }
    free(rows);
    if (st) goto done;
    out->n = nb;
    out->bin = bin;
    out->dx = scale * bin;
    out->diam = WF_PUPIL_DIAM;
    out->from_data = 1;
    snprintf(out->source, sizeof out->source, "%s (bin %d, %s)", path, bin,
             binning == WF_PUPIL_BIN_MEAN ? "mean" : "any-open");
    finish_pupil(out);
    if (out->i1 < 0) st = wf_error(WF_ERR_INPUT, "%s: the pupil mask has no open sample", path);
done:
    if (f) {
        int s2 = 0;
        fits_close_file(f, &s2);
    }
    free(mem);
    if (st) wf_pupil_free(out);
    return st;
}

static int geometry_open(const wf_pupil_geometry *g, const double *cs, double u, double v)
{
    double r2 = u * u + v * v, R = 0.5 * g->diam, Ro = R * g->obscuration;
    if (r2 >= R * R || r2 < Ro * Ro) return 0;
    for (int k = 0; k < g->nstruts; k++) {
        double c = cs[2 * k], s = cs[2 * k + 1];
        double along = u * c + v * s, left = -u * s + v * c;
        if (along > 0.0 && fabs(left - g->strut[k].offset_m) < 0.5 * g->strut[k].width_m)
            return 0;
    }
    return 1;
}

wf_status wf_pupil_analytic(const wf_pupil_geometry *g, int bin, wf_pupil_binning binning,
                            wf_pupil *out)
{
    memset(out, 0, sizeof *out);
    wf_status st = check_bin(bin, WF_PUPIL_NATIVE_N, "analytic pupil");
    if (st) return st;
    double extent = WF_PUPIL_NATIVE_N * WF_PUPIL_NATIVE_DX;
    if (!(g->diam > 0.0) || g->diam > extent)
        return wf_error(WF_ERR_RANGE, "analytic pupil: diameter %g m is not in (0, %g]", g->diam,
                        extent);
    if (!(g->obscuration >= 0.0 && g->obscuration < 1.0))
        return wf_error(WF_ERR_RANGE, "analytic pupil: obscuration %g is not in [0, 1)",
                        g->obscuration);
    if (g->nstruts < 0 || g->nstruts > WF_PUPIL_MAX_STRUTS)
        return wf_error(WF_ERR_RANGE, "analytic pupil: %d struts (0..%d)", g->nstruts,
                        WF_PUPIL_MAX_STRUTS);
    double cs[2 * WF_PUPIL_MAX_STRUTS];
    for (int k = 0; k < g->nstruts; k++) {
        if (!(g->strut[k].width_m >= 0.0) || !isfinite(g->strut[k].offset_m) ||
            !isfinite(g->strut[k].angle_deg))
            return wf_error(WF_ERR_RANGE, "analytic pupil: strut %d has a bad width/offset/angle",
                            k);
        cs[2 * k] = cos(g->strut[k].angle_deg * PI / 180.0);
        cs[2 * k + 1] = sin(g->strut[k].angle_deg * PI / 180.0);
    }
    int nb = WF_PUPIL_NATIVE_N / bin;
    out->amp = malloc((size_t)nb * nb * sizeof(float));
    if (!out->amp) return wf_error(WF_ERR_NOMEM, "analytic pupil: cannot allocate %dx%d", nb, nb);
    double dx0 = WF_PUPIL_NATIVE_DX;
    /* Native sample t of binned sample I lies at (I - nb/2) bin dx0 + (t - (bin-1)/2) dx0 from
     * the axis: the geometry is centred on the binned grid's axis at every binning. */
    for (int J = 0; J < nb; J++)
        for (int I = 0; I < nb; I++) {
            int open = 0;
            for (int t = 0; t < bin; t++)
                for (int s = 0; s < bin; s++) {
                    double u = ((I - nb / 2) * bin + s - 0.5 * (bin - 1)) * dx0;
                    double v = ((J - nb / 2) * bin + t - 0.5 * (bin - 1)) * dx0;
                    open += geometry_open(g, cs, u, v);
                }
            out->amp[(size_t)J * nb + I] = binning == WF_PUPIL_BIN_MEAN
                                               ? (float)open / (float)(bin * bin)
                                               : (float)(open > 0);
        }
    out->n = nb;
    out->bin = bin;
    out->dx = dx0 * bin;
    out->diam = g->diam;
    out->from_data = 0;
    snprintf(out->source, sizeof out->source,
             "analytic: D %.4g m, obscuration %.4g, %d struts (bin %d, %s)", g->diam,
             g->obscuration, g->nstruts, bin, binning == WF_PUPIL_BIN_MEAN ? "mean" : "any-open");
    finish_pupil(out);
    if (out->i1 < 0) {
        wf_pupil_free(out);
        return wf_error(WF_ERR_INPUT, "analytic pupil: no open sample");
    }
    return WF_OK;
}

/* Noll's ordering: row n holds j = n(n+1)/2 + 1 ... + n + 1; |m| runs 0,2,2,4,4.. (n even) or
 * 1,1,3,3.. (n odd); even j carries cos mφ and odd j sin mφ. */
static void noll_nm(int j, int *n_out, int *m_out, int *is_sin)
{
    int n = 0;
    while ((n + 1) * (n + 2) / 2 < j) n++;
    int k = j - n * (n + 1) / 2 - 1;
    int m = n % 2 == 0 ? 2 * ((k + 1) / 2) : 2 * (k / 2) + 1;
    *n_out = n;
    *m_out = m;
    *is_sin = m != 0 && j % 2 == 1;
}

static double factorial(int k)
{
    double f = 1.0;
    for (int i = 2; i <= k; i++) f *= i;
    return f;
}

wf_status wf_pupil_zernike_term(int j, wf_zernike_term *t)
{
    if (j < 1 || j > WF_ZERNIKE_MAX)
        return wf_error(WF_ERR_RANGE, "Zernike: Noll index %d is not 1..%d", j, WF_ZERNIKE_MAX);
    int n, m, is_sin;
    noll_nm(j, &n, &m, &is_sin);
    t->m = m;
    t->is_sin = is_sin;
    t->ncoef = 0;
    /* R_n^m(ρ) = ρ^m Σ_s c_s ρ^(n-m-2s), highest s (lowest power) first */
    for (int s = (n - m) / 2; s >= 0; s--)
        t->coef[t->ncoef++] = (s % 2 ? -1.0 : 1.0) * factorial(n - s) /
                              (factorial(s) * factorial((n + m) / 2 - s) * factorial((n - m) / 2 - s));
    t->norm = m == 0 ? sqrt(n + 1.0) : sqrt(2.0 * (n + 1.0));
    return WF_OK;
}

double wf_pupil_zernike_eval(const wf_zernike_term *t, double x, double y)
{
    double r2 = x * x + y * y;
    /* ρ^m cos/sin(mφ) = Re/Im (x + iy)^m: no atan2 */
    double radial = 0.0, p = 1.0; /* p = (ρ²)^((n-m)/2 - s) */
    for (int k = 0; k < t->ncoef; k++) {
        radial += t->coef[k] * p;
        p *= r2;
    }
    double re = 1.0, im = 0.0;
    for (int k = 0; k < t->m; k++) {
        double u = re * x - im * y;
        im = re * y + im * x;
        re = u;
    }
    return t->norm * radial * (t->is_sin ? im : re);
}

wf_status wf_pupil_zernike(int j, double x, double y, double *out)
{
    wf_zernike_term t;
    wf_status st = wf_pupil_zernike_term(j, &t);
    if (st) return st;
    *out = wf_pupil_zernike_eval(&t, x, y);
    return WF_OK;
}

void wf_pupil_aberrations_none(wf_aberrations *out)
{
    memset(out, 0, sizeof *out);
    out->lambda_ref_nm = WF_ABERR_LAMBDA_NM;
    snprintf(out->source, sizeof out->source, "none (no data: flat wavefront)");
}

wf_status wf_pupil_aberrations_load(const char *data_dir, int sca, double x, double y,
                              wf_aberrations *out)
{
    wf_pupil_aberrations_none(out);
    if (!data_dir || !*data_dir) return wf_error(WF_ERR_INPUT, "aberrations: no data directory");
    if (sca < 1 || sca > 18) return wf_error(WF_ERR_RANGE, "aberrations: SCA %d is not 1..18", sca);
    if (!isfinite(x) || !isfinite(y))
        return wf_error(WF_ERR_RANGE, "aberrations: SCA position (%g, %g) is not finite", x, y);
    char name[64], path[1024];
    snprintf(name, sizeof name, "Roman_Cycle-9_WFI_zim_zernikes_082623_%02d.txt", sca);
    wf_status st = data_path(data_dir, name, path, sizeof path);
    if (st) return st;
    FILE *f = fopen(path, "r");
    if (!f) return wf_error(WF_ERR_IO, "%s: %s", path, strerror(errno));
    enum { NPT = 5, NCOL = 5 + WF_ZERNIKE_MAX };
    double d[NPT][NCOL];
    char line[4096];
    int npt = 0, lineno = 0;
    while (fgets(line, sizeof line, f)) {
        lineno++;
        char *p = line;
        while (*p == ' ' || *p == '\t') p++;
        if (*p == '\n' || *p == '\0' || *p == '#') continue;
        if (npt == NPT) {
            fclose(f);
            return wf_error(WF_ERR_INPUT, "%s:%d: more than %d field points", path, lineno, NPT);
        }
        for (int c = 0; c < NCOL; c++) {
            char *end;
            errno = 0;
            d[npt][c] = strtod(p, &end);
            if (end == p || errno || !isfinite(d[npt][c])) {
                fclose(f);
                return wf_error(WF_ERR_INPUT, "%s:%d: column %d is not a number (want %d columns: "
                                "point, x_mm, y_mm, X_mm, Y_mm, Z1..Z22)", path, lineno, c + 1,
                                NCOL);
            }
            p = end;
        }
        npt++;
    }
    fclose(f);
    if (npt != NPT)
        return wf_error(WF_ERR_INPUT, "%s: %d field points, want %d (centre and four corners)",
                        path, npt, NPT);
    /* GalSim's pixel positions: x = x_mm / 0.01 + 2044, y = 2044 - y_mm / 0.01 (the file's y
     * runs opposite to the SCA's, as GalSim's roman_psfs notes). */
    double px[NPT], py[NPT];
    int centre = 0;
    for (int k = 0; k < NPT; k++) {
        px[k] = d[k][1] / 0.01 + WF_SCA_NPIX / 2.0;
        py[k] = WF_SCA_NPIX / 2.0 - d[k][2] / 0.01;
        double r2 = d[k][1] * d[k][1] + d[k][2] * d[k][2];
        if (r2 < d[centre][1] * d[centre][1] + d[centre][2] * d[centre][2]) centre = k;
    }
    /* The corners are matched by quadrant, not by equal coordinates: the Cycle-9 corners differ
     * by 0.01 mm, so exact equality (as GalSim's bilinear code uses) would match nothing. */
    int q[4] = {-1, -1, -1, -1}; /* 0: low x low y, 1: low x high y, 2: high x low y, 3: high high */
    for (int k = 0; k < NPT; k++) {
        if (k == centre) continue;
        int idx = (px[k] > WF_SCA_NPIX / 2.0 ? 2 : 0) + (py[k] > WF_SCA_NPIX / 2.0 ? 1 : 0);
        if (q[idx] >= 0)
            return wf_error(WF_ERR_INPUT, "%s: two field points in one corner quadrant", path);
        q[idx] = k;
    }
    double xlo = 0.5 * (px[q[0]] + px[q[1]]), xhi = 0.5 * (px[q[2]] + px[q[3]]);
    double ylo = 0.5 * (py[q[0]] + py[q[2]]), yhi = 0.5 * (py[q[1]] + py[q[3]]);
    double fx = (x - xlo) / (xhi - xlo), fy = (y - ylo) / (yhi - ylo);
    fx = fx < 0.0 ? 0.0 : fx > 1.0 ? 1.0 : fx;
    fy = fy < 0.0 ? 0.0 : fy > 1.0 ? 1.0 : fy;
    double w[4] = {(1 - fx) * (1 - fy), (1 - fx) * fy, fx * (1 - fy), fx * fy};
    for (int j = 4; j <= WF_ZERNIKE_MAX; j++) {
        double z = 0.0;
        for (int c = 0; c < 4; c++) z += w[c] * d[q[c]][4 + j];
        out->z[j] = z;
    }
    out->lambda_ref_nm = WF_ABERR_LAMBDA_NM;
    snprintf(out->source, sizeof out->source, "%s (bilinear at x=%.6g y=%.6g)", path, x, y);
    return WF_OK;
}
