// Generated once with numpy and workers/kernels (shading.direct_irradiance with no caster, prt.group_mean,
// the einsum of workers/prt_relight._apply): the browser's npy reader and PRT relight math must give the same.
import { describe, expect, it } from 'vitest';
import { NpyError, parseNpy, toFloat64 } from '../src/loader/npy.js';
import { directVector, packPrtCoefficients, relightCoefficients } from '../src/math/prt.js';

const FX = {"table": "k05VTVBZAQB2AHsnZGVzY3InOiAnPGY0JywgJ2ZvcnRyYW5fb3JkZXInOiBGYWxzZSwgJ3NoYXBlJzogKDEwLCA5KSwgfSAgICAgICAgICAgICAgICAgICAgICAgICAgICAgICAgICAgICAgICAgICAgICAgICAgICAgICAgIArLJVS/xsAGv6ZAGj/ZrTC/xJFovsnlLz+SCTk/mv85P2zNGD+SRCg+X85Pv770CL6FtSY/UE/SPdV9QD/qQVg/WCawPnauSz+dnCu9szYuv/408D7vYWW/XqulPsGqm74O96I+TgNgPzv3Ij/IzEW/wcNevrUiCT2rVWm/GKEaPo/swz4d9B8/xx9hP3w8QD/lEg6+c8MxPsCL8z5ZecO+44lsv2i1tzzSwEA/DJNzPpHA6j7dm2k/X/rcvsIcmD4WpAe9d+hhP0c/8D6I04Q+osKrPsgMsz7Z7Mg+A0HUvrE8f79fCS0+GR14PyV9N76SEU0/ONSTPgvC0D5jaXI/6W/OvnR6vr6pJD+/iCXxPuKE8D6nhAs/XmxLP2IrYD9ajkg/6GkuPv4Ha71XZ4K+RZZtv18Ziz58GTI/SvyyPmTcFD/36gs/fXZwv6ju0z5WZXK/gyeGPhoJPz42tTE/Sf1xPgYJLT8=", "offsets": "k05VTVBZAQB2AHsnZGVzY3InOiAnPGk0JywgJ2ZvcnRyYW5fb3JkZXInOiBGYWxzZSwgJ3NoYXBlJzogKDYsKSwgfSAgICAgICAgICAgICAgICAgICAgICAgICAgICAgICAgICAgICAgICAgICAgICAgICAgICAgICAgICAgIAoAAAAAAgAAAAQAAAAGAAAACAAAAAoAAAA=", "transfer": "k05VTVBZAQB2AHsnZGVzY3InOiAnPGY0JywgJ2ZvcnRyYW5fb3JkZXInOiBGYWxzZSwgJ3NoYXBlJzogKDMsIDYsIDYpLCB9ICAgICAgICAgICAgICAgICAgICAgICAgICAgICAgICAgICAgICAgICAgICAgICAgICAgICAgIAqIXq8/xe26v6yrGL8VeqS+iAJmPhlKEz9p4p+/FXHdv0SlkLsPVps/j85BP4/TXD45YqK+uiKWPtUseb5zNFE/52BLvzJ2CT6y4OK9mhkLP6QHZj7EMyNA69O/PxWVvz87hwLA+z2uvujNG79xYAg/ktsRwPlVlj/pkog/QqqmvyiCer+cGU2/C1cxPa4WJD+REANAIy9Kvgx7RD/ZJR8+REXhPw/+PT+pLK8/Q/GJv8DaRL5kU1C/HqLAPxdbKD/kO5y+36nnvv8l+D42lTO/Eztuv5xp9j71ox1Abwp8vjhNDr946JW/pOGqv01lBj86zlk/klEWPGZHqj6sZe09ifsNPi5Zw796juq+Q0/kPZ59SL+Z7vO+3LFRvxPAqr5OZVo/TSvQvkeQHb7ZT1A/qQ8lP5D82D+CygXAHFtbP/Ht9r6n7Ak+x3RWPwqoij9yCYU/StQePm0Jzj//4ZC+kF0QvkiiTD++Jg2/SkwKQFx1gj+gPAtAkdHZvC8kxL6iDis+NQ08P6lhFr9EaMI+IamJvKnOzj/Tpim/oeiFPz7UJL8f7HW/L9Y1vwNYmL8=", "lights": [{"type": "point", "position": [0.3, 2.0, -0.4], "color": [1.0, 0.8, 0.6], "intensity": 12.0, "range": null}, {"type": "spot", "position": [-1.5, 1.0, 0.5], "direction": [0.7, -0.5, -0.1], "color": [0.5, 0.5, 1.0], "intensity": 30.0, "range": 6.0, "inner_cone_angle": 0.3, "outer_cone_angle": 0.9}, {"type": "directional", "direction": [0.2, -1.0, 0.3], "color": [1, 1, 1], "intensity": 2.0}], "n": 6, "x": [0.020201505338162753, 0.011730029083647257, 0.01964894411581139, 0.5605293121129394, 1.0462221634790774, 1.4440300537224133, 0.14607646279316816, 0.17552818376666174, 0.2179283247735248, 0.8169015913689521, 0.5940894134917369, 0.8792718928467793, 0.28607181242782637, 0.0947041225330413, 0.42333459706676707], "u": [-0.47685989926824335, 1.1163131160354887, 3.3622488726245825, 0.436973345840592, -0.6840452726090954, 3.466994751179259, 0.7025574275912907, -0.30980519142884655, 1.6907905707755093, 4.406122073133269, -0.5081179456033905, 4.560449409112437, 0.6858097577862706, -1.7013620731301364, 4.100772692190542, -0.8256409978649734, -0.7935600222241672, -1.8786105931797774], "int64": "k05VTVBZAQB2AHsnZGVzY3InOiAnPGk4JywgJ2ZvcnRyYW5fb3JkZXInOiBGYWxzZSwgJ3NoYXBlJzogKDIsIDMpLCB9ICAgICAgICAgICAgICAgICAgICAgICAgICAgICAgICAgICAgICAgICAgICAgICAgICAgICAgICAgIAoBAAAAAAAAAP7/////////AwAAAAAAAAAEAAAAAAAAAAUAAAAAAAAA+v////////8=", "float64": "k05VTVBZAQB2AHsnZGVzY3InOiAnPGY4JywgJ2ZvcnRyYW5fb3JkZXInOiBGYWxzZSwgJ3NoYXBlJzogKDMsKSwgfSAgICAgICAgICAgICAgICAgICAgICAgICAgICAgICAgICAgICAgICAgICAgICAgICAgICAgICAgICAgIAoAAAAAAAD4PwAAAAAAAALAWfP4wh9upQE=", "uint8_3d": "k05VTVBZAQB2AHsnZGVzY3InOiAnfHUxJywgJ2ZvcnRyYW5fb3JkZXInOiBGYWxzZSwgJ3NoYXBlJzogKDIsIDMsIDQpLCB9ICAgICAgICAgICAgICAgICAgICAgICAgICAgICAgICAgICAgICAgICAgICAgICAgICAgICAgIAoAAQIDBAUGBwgJCgsMDQ4PEBESExQVFhc="};
const bytes = (b64) => Uint8Array.from(Buffer.from(b64, 'base64'));
const close = (got, want, tol) => want.forEach((w, i) => expect(Math.abs(got[i] - w)).toBeLessThanOrEqual(tol * (1 + Math.abs(w))));

describe('npy reader', () => {
  it('reads float32, int32, float64, int64 and uint8 arrays with their shapes', () => {
    const t = parseNpy(bytes(FX.table));
    expect(t.dtype).toBe('<f4');
    expect(t.shape).toEqual([10, 9]);
    expect(t.data).toBeInstanceOf(Float32Array);
    const o = parseNpy(bytes(FX.offsets));
    expect(o.shape).toEqual([6]);
    expect(Array.from(o.data)).toEqual([0, 2, 4, 6, 8, 10]);
    expect(parseNpy(bytes(FX.transfer)).shape).toEqual([3, 6, 6]);
    const f8 = parseNpy(bytes(FX.float64));
    expect(Array.from(f8.data)).toEqual([1.5, -2.25, 1e-300]);
    const i8 = parseNpy(bytes(FX.int64));
    expect(i8.shape).toEqual([2, 3]);
    expect(Array.from(toFloat64(i8))).toEqual([1, -2, 3, 4, 5, -6]);
    const u8 = parseNpy(bytes(FX.uint8_3d));
    expect(u8.shape).toEqual([2, 3, 4]);
    expect(u8.data[23]).toBe(23);
  });
  it('reads arrays whose data is not aligned in the buffer', () => {
    const b = bytes(FX.float64);
    const shifted = new Uint8Array(b.length + 1);
    shifted.set(b, 1);
    expect(Array.from(parseNpy(shifted.subarray(1)).data)).toEqual([1.5, -2.25, 1e-300]);
  });
  it('refuses what it cannot read', () => {
    expect(() => parseNpy(new Uint8Array(20))).toThrow(NpyError);
    const b = bytes(FX.float64);
    expect(() => parseNpy(b.subarray(0, b.length - 4))).toThrow(/truncated/);
  });
});

describe('PRT relight math (workers/prt_relight.py, unshadowed)', () => {
  const table = parseNpy(bytes(FX.table)).data;
  const offsets = parseNpy(bytes(FX.offsets)).data;
  const transfer = parseNpy(bytes(FX.transfer)).data;
  it('direct vector x at the measurement points = numpy', () => {
    close(directVector(table, offsets, FX.lights), FX.x, 1e-5);
  });
  it('coefficients u = T_c [x_c, |x_c|] = numpy', () => {
    const u = relightCoefficients(transfer, FX.n, directVector(table, offsets, FX.lights));
    close(u, FX.u, 1e-5);
  });
  it('coefficients with the L1 norm (prt.norm "l1": u_c = T_c [x_c, sum |x_c|]) = numpy', () => {
    const uL1 = [-0.023428753477227948, 1.637803380372787, 5.443410795197694, 0.6069270866135194, -0.22194303405053817,
      4.796876238194207, 0.8083515270405587, 0.02837077713271663, 2.672133101490915, 5.585696153887174,
      -0.13922926217794074, 4.0901416286700405, 1.6114286769062427, -2.773744527880377, 6.084302840192413,
      -0.3204936056520822, -1.0278973066279977, -3.3397706253402437];  // kprt.direct_norm(x, 0, "l1"), the einsum
    close(relightCoefficients(transfer, FX.n, Float64Array.from(FX.x), 'l1'), uL1, 1e-5);
    close(relightCoefficients(transfer, FX.n, Float64Array.from(FX.x), 'l2'), FX.u, 1e-5);
  });
  it('packs uPrtCoef as mode_prt.glsl reads it', () => {
    const u = Float64Array.from(FX.u);
    const c = packPrtCoefficients(u, FX.n, 16);
    expect(c.length).toBe(3 * 16 * 4);
    // slot 5 (group 1, component 1) of channel g (c = 1) sits at vec4 [16 + 1].y
    expect(c[(16 + 1) * 4 + 1]).toBeCloseTo(u[5 * 3 + 1], 5);
    expect(c[(2 * 16 + 0) * 4 + 0]).toBeCloseTo(u[2], 5);
    expect(c[(0 * 16 + 1) * 4 + 2]).toBe(0);  // past n
  });
});
